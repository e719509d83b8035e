#!/usr/bin/env python3
"""Decode every message of every dvnav MCAP episode log with the reference Python readers.

An independent check of dvnav's logs: the `mcap` package reads the files (summary, chunk
indexes, chunk CRCs) and `mcap-protobuf-support` decodes each message from the protobuf
descriptors embedded in the file's schemas, with no dvnav code. Usage:

    python3 scripts/check_mcap.py RUN_DIR_OR_FILE [...]

Exits 1 on any error: a file without a summary section (unfinished: a killed or running
actor), an undecodable message, a missing `dvnav` metadata record, log times that go
backwards, an episode summary without all its steps, or no files at all.

A killed actor's files are the exception: under a run directory whose `run_summary.json`
names a process in `actor_failures`, that process's unfinished files (`mcap/<process>/`) are
read as a stream (`NonSeekingReader`, as any reader of a file without a summary must), and
must end at a record boundary with every complete episode decodable; only the episode that
was open when the process died may be missing. `--expect-killed` makes a run without any such
file, or without one complete episode in them, an error (`make check-mcap`'s killed-actor run).
"""

import collections
import json
import os
import sys
from pathlib import Path

from mcap.exceptions import EndOfFile
from mcap.reader import NonSeekingReader, make_reader
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


def check_messages(path, messages, counts, errors) -> None:
    """Checks decoded messages in file order, counting them by topic into `counts`."""
    steps_of: collections.Counter = collections.Counter()
    last_time = 0
    for schema, channel, message, decoded in messages:
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


def has_summary(path: Path) -> bool:
    with path.open("rb") as f:
        try:
            return make_reader(f).get_summary() is not None
        except Exception:  # no footer to read: an unfinished file
            return False


def check_unfinished(path: Path) -> tuple[collections.Counter, list[str], int]:
    """A killed process's file, read as a stream to its end."""
    errors: list[str] = []
    counts: collections.Counter = collections.Counter()
    size = os.path.getsize(path)
    with path.open("rb") as f:
        reader = NonSeekingReader(f, decoder_factories=[DecoderFactory()])
        try:
            check_messages(path, reader.iter_decoded_messages(log_time_order=False), counts, errors)
        except EndOfFile:
            # The stream ends where the process stopped writing: at a record boundary, or the
            # records before it were not whole.
            if f.tell() != size:
                errors.append(f"{path}: stream ends at byte {f.tell()} of {size} (a torn record)")
    metadata = {}
    with path.open("rb") as f:
        try:
            for m in NonSeekingReader(f).iter_metadata():
                metadata[m.name] = m.metadata
        except EndOfFile:
            pass  # the end of what was written; torn records are reported above
        missing = METADATA_KEYS - set(metadata.get("dvnav", {}))
        # A process killed just after opening a file (a rotation) leaves it empty or with only
        # its header: the metadata record is buffered with the first chunk, so a file with no
        # message decoded may lack it and has lost nothing. One with messages must have it.
        if missing and sum(counts.values()) > 0:
            errors.append(f"{path}: metadata record `dvnav` lacks {sorted(missing)}")
    # Counted as they were decoded, so those before the end of the stream are in.
    return counts, errors, counts["/dvnav/episode"]


def killed_processes(root: Path) -> set[str]:
    """Processes `run_summary.json` under `root` says were killed (their files may be unfinished)."""
    summary = root / "run_summary.json"
    if not summary.exists():
        return set()
    failures = json.loads(summary.read_text()).get("actor_failures") or []
    return {f["process"] for f in failures if f.get("process")}


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
        check_messages(path, reader.iter_decoded_messages(log_time_order=False), counts, errors)
        stats = summary.statistics
        if stats is not None and stats.message_count != sum(counts.values()):
            errors.append(
                f"{path}: statistics say {stats.message_count} messages, decoded {sum(counts.values())}"
            )
    return counts, errors


def main(argv: list[str]) -> int:
    expect_killed = "--expect-killed" in argv
    args = [a for a in argv[1:] if a != "--expect-killed"]
    if not args:
        print("usage: check_mcap.py [--expect-killed] RUN_DIR_OR_FILE [...]", file=sys.stderr)
        return 2
    files: list[tuple[Path, bool]] = []
    for arg in args:
        p = Path(arg)
        if p.is_dir():
            killed = killed_processes(p)
            files.extend((f, f.parent.name in killed) for f in sorted(p.rglob("*.mcap")))
        else:
            files.append((p, False))
    if not files:
        print(f"check_mcap: no .mcap files under {' '.join(args)}", file=sys.stderr)
        return 1
    total: collections.Counter = collections.Counter()
    errors: list[str] = []
    unfinished = killed_episodes = 0
    for f, of_killed in files:
        try:
            if of_killed and not has_summary(f):
                unfinished += 1
                counts, errs, episodes = check_unfinished(f)
                killed_episodes += episodes
            else:
                counts, errs = check_file(f)
        except Exception as e:  # any reader or decoder failure is a finding
            counts, errs = collections.Counter(), [f"{f}: {type(e).__name__}: {e}"]
        total.update(counts)
        errors.extend(errs)
    if unfinished or expect_killed:
        print(
            f"check_mcap: {unfinished} unfinished files of killed actors, read as a stream: "
            f"{killed_episodes} complete episodes decoded"
        )
    if expect_killed and (unfinished == 0 or killed_episodes == 0):
        errors.append("--expect-killed: no complete episode in a killed actor's unfinished files")
    for e in errors[:50]:
        print(f"error: {e}", file=sys.stderr)
    by_topic = ", ".join(f"{t} {n}" for t, n in sorted(total.items()))
    status = "ok" if not errors else f"{len(errors)} errors"
    print(f"check_mcap: {len(files)} files, {sum(total.values())} messages decoded ({by_topic}): {status}")
    return 0 if not errors else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv))
