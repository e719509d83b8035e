#!/usr/bin/env python3
"""Decode every message of every dvnav MCAP episode log with the reference Python readers.

An independent check of dvnav's logs: the `mcap` package reads the files (summary, chunk
indexes, chunk CRCs) and `mcap-protobuf-support` decodes each message from the protobuf
descriptors embedded in the file's schemas, with no dvnav code. Usage:

    python3 scripts/check_mcap.py RUN_DIR_OR_FILE [...]

Exits 1 on any error: a file without a summary section (unfinished: a killed or running
actor), an undecodable message, a missing `dvnav` metadata record, log times that go
backwards, an episode summary without all its steps, or no files at all.
"""

import collections
import sys
from pathlib import Path

from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

EXPECTED_SCHEMAS = {
    "/scan": "foxglove.LaserScan",
    "/tf": "foxglove.FrameTransform",
    "/scene": "foxglove.SceneUpdate",
    "/path": "foxglove.SceneUpdate",
    "/dvnav/step": "dvnav.v1.StepRecord",
    "/dvnav/episode": "dvnav.v1.EpisodeSummary",
}
METADATA_KEYS = {"run_id", "actor", "config_hash", "dvnav_version"}


def check_file(path: Path) -> tuple[collections.Counter, list[str]]:
    errors: list[str] = []
    counts: collections.Counter = collections.Counter()
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        if summary is None:
            return counts, [f"{path}: no summary section (unfinished file)"]
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
        missing = METADATA_KEYS - set(metadata.get("dvnav", {}))
        if missing:
            errors.append(f"{path}: metadata record `dvnav` lacks {sorted(missing)}")
        steps_of: collections.Counter = collections.Counter()
        last_time = 0
        for schema, channel, message, decoded in reader.iter_decoded_messages(
            log_time_order=False
        ):
            want = EXPECTED_SCHEMAS.get(channel.topic)
            if want is None or schema is None or schema.name != want:
                errors.append(f"{path}: topic {channel.topic} has schema {schema and schema.name}")
            if message.log_time < last_time:
                errors.append(f"{path}: log time goes backwards at {channel.topic} {message.sequence}")
            last_time = message.log_time
            counts[channel.topic] += 1
            if channel.topic == "/dvnav/step":
                steps_of[decoded.episode_id] += 1
            elif channel.topic == "/dvnav/episode":
                if steps_of[decoded.episode_id] != decoded.steps + 1:
                    errors.append(
                        f"{path}: episode {decoded.episode_id} has {steps_of[decoded.episode_id]} "
                        f"step records, its summary says {decoded.steps + 1}"
                    )
        stats = summary.statistics
        if stats is not None and stats.message_count != sum(counts.values()):
            errors.append(
                f"{path}: statistics say {stats.message_count} messages, decoded {sum(counts.values())}"
            )
    return counts, errors


def main(argv: list[str]) -> int:
    if len(argv) < 2:
        print("usage: check_mcap.py RUN_DIR_OR_FILE [...]", file=sys.stderr)
        return 2
    files: list[Path] = []
    for arg in argv[1:]:
        p = Path(arg)
        files.extend(sorted(p.rglob("*.mcap")) if p.is_dir() else [p])
    if not files:
        print(f"check_mcap: no .mcap files under {' '.join(argv[1:])}", file=sys.stderr)
        return 1
    total: collections.Counter = collections.Counter()
    errors: list[str] = []
    for f in files:
        try:
            counts, errs = check_file(f)
        except Exception as e:  # any reader or decoder failure is a finding
            counts, errs = collections.Counter(), [f"{f}: {type(e).__name__}: {e}"]
        total.update(counts)
        errors.extend(errs)
    for e in errors[:50]:
        print(f"error: {e}", file=sys.stderr)
    by_topic = ", ".join(f"{t} {n}" for t, n in sorted(total.items()))
    status = "ok" if not errors else f"{len(errors)} errors"
    print(f"check_mcap: {len(files)} files, {sum(total.values())} messages decoded ({by_topic}): {status}")
    return 0 if not errors else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv))
