#!/usr/bin/env python3
"""Checks deploy/ against the code (`make check-deploy`).

- every Kubernetes manifest in deploy/k8s parses as YAML and is listed in kustomization.yaml;
- every `--flag` a container, or a systemd unit's ExecStart, passes to `dvnav learner` or
  `dvnav actor` is one that subcommand's `--help` lists (the real binary is asked);
- every probe's path is one the learner's HTTP server routes (`HTTP_PATHS` in
  learner/src/metrics/http.rs, whose unit test checks each is answered), on a named container port
  that is the port of `--metrics-addr`; `--listen` is the port named grpc;
- Service selectors and target ports, volumes, ConfigMaps, PersistentVolumeClaims and the
  token Secret refer to things that exist (the Secret is created by hand: the README's command
  must name it), `$(VAR)` in arguments is defined, the actors' `--learner` URL is the learner
  Service's gRPC port, and the run config in the ConfigMap only uses keys of
  configs/default.toml;
- deploy/Dockerfile is multi-stage, ends with the dvnav binary as entrypoint and exposes the
  ports the manifests use.

Usage: check_deploy.py PATH/TO/dvnav [--root REPO]
"""

import re
import subprocess
import sys
import tomllib
from pathlib import Path
from urllib.parse import urlparse

import yaml

errors: list[str] = []


def error(where: str, msg: str) -> None:
    errors.append(f"{where}: {msg}")


def help_flags(binary: str, sub: str, cache: dict[str, set[str]]) -> set[str]:
    if sub not in cache:
        out = subprocess.run(
            [binary, sub, "--help"], capture_output=True, text=True, check=False
        )
        if out.returncode != 0:
            error(binary, f"`dvnav {sub} --help` failed: {out.stderr.strip()}")
            cache[sub] = set()
        else:
            cache[sub] = set(re.findall(r"(?<![\w-])--[a-z0-9][a-z0-9-]*", out.stdout))
    return cache[sub]


def check_args(where: str, args: list[str], binary: str, cache: dict[str, set[str]]) -> None:
    if not args or args[0] not in ("learner", "actor"):
        error(where, f"the first argument must be the subcommand learner or actor: {args[:1]}")
        return
    known = help_flags(binary, args[0], cache)
    for a in args[1:]:
        flag = a.split("=", 1)[0]
        if flag.startswith("--") and flag not in known:
            error(where, f"`dvnav {args[0]}` has no flag {flag}")


def flag_value(args: list[str], flag: str) -> str | None:
    for i, a in enumerate(args):
        if a == flag and i + 1 < len(args):
            return args[i + 1]
        if a.startswith(flag + "="):
            return a.split("=", 1)[1]
    return None


def port_of(addr: str | None) -> int | None:
    if not addr or ":" not in addr:
        return None
    try:
        return int(addr.rsplit(":", 1)[1])
    except ValueError:
        return None


def toml_keys(table: dict, prefix: str = "") -> set[str]:
    keys = set()
    for k, v in table.items():
        path = f"{prefix}{k}"
        keys.add(path)
        if isinstance(v, dict):
            keys |= toml_keys(v, path + ".")
    return keys


def main() -> int:
    argv = sys.argv[1:]
    if not argv:
        print(__doc__)
        return 2
    binary = argv[0]
    root = Path(argv[argv.index("--root") + 1]) if "--root" in argv else Path(__file__).parents[1]
    k8s = root / "deploy" / "k8s"
    cache: dict[str, set[str]] = {}

    metrics_rs = (root / "learner" / "src" / "metrics" / "http.rs").read_text()
    m = re.search(r"pub const HTTP_PATHS: \[&str; \d+\] = \[([^\]]*)\]", metrics_rs)
    routed = set(re.findall(r'"([^"]*)"', m.group(1))) if m else set()
    if not routed:
        error("learner/src/metrics/http.rs", "no HTTP_PATHS list found")
    readme = (root / "README.md").read_text()
    default_keys = toml_keys(tomllib.loads((root / "configs" / "default.toml").read_text()))

    # Parse every manifest.
    kust = yaml.safe_load((k8s / "kustomization.yaml").read_text())
    listed = set(kust.get("resources", []))
    files = {p.name for p in k8s.glob("*.yaml")} - {"kustomization.yaml"}
    for missing in sorted(listed - files):
        error("kustomization.yaml", f"lists {missing}, which does not exist")
    for unlisted in sorted(files - listed):
        error("kustomization.yaml", f"does not list {unlisted}")
    images = {i["name"] for i in kust.get("images", [])}
    objects = []
    for name in sorted(files):
        try:
            docs = [d for d in yaml.safe_load_all((k8s / name).read_text()) if d is not None]
        except yaml.YAMLError as e:
            error(name, f"not valid YAML: {e}")
            continue
        for d in docs:
            if not all(k in d for k in ("apiVersion", "kind", "metadata")) or "name" not in d[
                "metadata"
            ]:
                error(name, "an object without apiVersion, kind or metadata.name")
                continue
            objects.append((name, d))
    by_kind: dict[str, dict[str, dict]] = {}
    for name, d in objects:
        kinds = by_kind.setdefault(d["kind"], {})
        if d["metadata"]["name"] in kinds:
            error(name, f"two {d['kind']}s named {d['metadata']['name']}")
        kinds[d["metadata"]["name"]] = d

    workloads = {
        n: d for k in ("Deployment", "StatefulSet") for n, d in by_kind.get(k, {}).items()
    }
    secrets_used: set[str] = set()
    pod_ports: dict[str, tuple[dict, dict[str, int]]] = {}  # workload -> (labels, ports)
    actor_urls: list[tuple[str, str]] = []
    for wname, w in workloads.items():
        spec = w["spec"]
        tmpl = spec["template"]
        labels = tmpl["metadata"].get("labels", {})
        for k, v in spec["selector"].get("matchLabels", {}).items():
            if labels.get(k) != v:
                error(wname, f"selector {k}={v} does not match the pod template's labels")
        volumes = {v["name"]: v for v in tmpl["spec"].get("volumes", [])}
        for v in volumes.values():
            if "configMap" in v and v["configMap"]["name"] not in by_kind.get("ConfigMap", {}):
                error(wname, f"volume {v['name']}: no ConfigMap {v['configMap']['name']}")
            if "persistentVolumeClaim" in v:
                claim = v["persistentVolumeClaim"]["claimName"]
                if claim not in by_kind.get("PersistentVolumeClaim", {}):
                    error(wname, f"volume {v['name']}: no PersistentVolumeClaim {claim}")
            if "secret" in v:
                secrets_used.add(v["secret"]["secretName"])
        all_ports: dict[str, int] = {}
        for c in tmpl["spec"]["containers"]:
            where = f"{wname}/{c['name']}"
            if c.get("image") not in images:
                error(where, f"image {c.get('image')} is not set by kustomization.yaml images")
            args = [str(a) for a in c.get("args", [])]
            check_args(where, args, binary, cache)
            env = {e["name"] for e in c.get("env", [])}
            for a in args:
                for var in re.findall(r"\$\(([A-Za-z_][A-Za-z0-9_]*)\)", a):
                    if var not in env:
                        error(where, f"$({var}) in the arguments is not in env")
            mounts = {}
            for vm in c.get("volumeMounts", []):
                if vm["name"] not in volumes:
                    error(where, f"volumeMount {vm['name']} has no volume")
                mounts[vm["mountPath"]] = vm["name"]
            for flag in ("--config", "--token-file", "--out"):
                path = flag_value(args, flag)
                if path and not any(path.startswith(mp.rstrip("/") + "/") or path == mp
                                    for mp in mounts):
                    error(where, f"{flag} {path} is on no mounted volume")
                if path and flag == "--config":
                    mp = max((p for p in mounts if path.startswith(p.rstrip("/") + "/")),
                             key=len, default=None)
                    vol = volumes.get(mounts.get(mp, ""), {})
                    cm = by_kind.get("ConfigMap", {}).get(vol.get("configMap", {}).get("name"))
                    key = path[len(mp.rstrip("/")) + 1:] if mp else None
                    if cm is None or key not in cm.get("data", {}):
                        error(where, f"--config {path}: no such key in a mounted ConfigMap")
                    else:
                        try:
                            keys = toml_keys(tomllib.loads(cm["data"][key]))
                        except tomllib.TOMLDecodeError as e:
                            error(f"ConfigMap {cm['metadata']['name']}", f"{key}: {e}")
                            keys = set()
                        for k in sorted(keys - default_keys):
                            error(f"ConfigMap {cm['metadata']['name']}",
                                  f"{key}: `{k}` is not a key of configs/default.toml")
            ports = {p["name"]: p["containerPort"] for p in c.get("ports", []) if "name" in p}
            all_ports.update(ports)
            if args and args[0] == "learner":
                listen, metrics = port_of(flag_value(args, "--listen")), port_of(
                    flag_value(args, "--metrics-addr"))
                if listen is not None and ports.get("grpc") != listen:
                    error(where, f"--listen port {listen} is not the containerPort named grpc")
                if metrics is not None and ports.get("metrics") != metrics:
                    error(where, f"--metrics-addr port {metrics} is not the port named metrics")
            if args and args[0] == "actor":
                url = flag_value(args, "--learner")
                if url:
                    actor_urls.append((where, url))
            probes = [(k, c[k]) for k in ("startupProbe", "livenessProbe", "readinessProbe")
                      if k in c]
            for kind, probe in probes:
                http = probe.get("httpGet")
                if http is None:
                    continue
                if http.get("path") not in routed:
                    error(where, f"{kind} path {http.get('path')} is not routed by the learner "
                                 f"(HTTP_PATHS: {sorted(routed)})")
                port = http.get("port")
                number = ports.get(port) if isinstance(port, str) else port
                if number is None:
                    error(where, f"{kind} port {port} is not a container port")
                elif number != port_of(flag_value(args, "--metrics-addr")):
                    error(where, f"{kind} port {port} is not the --metrics-addr port")
        pod_ports[wname] = (labels, all_ports)

    services = by_kind.get("Service", {})
    for sname, s in services.items():
        sel = s["spec"].get("selector", {})
        targets = [w for w, (labels, _) in pod_ports.items()
                   if all(labels.get(k) == v for k, v in sel.items())]
        if not targets:
            error(f"Service {sname}", f"selector {sel} matches no pod template")
        for p in s["spec"].get("ports", []):
            tp = p.get("targetPort", p["port"])
            for w in targets:
                ports = pod_ports[w][1]
                if isinstance(tp, str) and tp not in ports:
                    error(f"Service {sname}", f"targetPort {tp} is not a port of {w}")
                if isinstance(tp, int) and tp not in ports.values():
                    error(f"Service {sname}", f"targetPort {tp} is not a port of {w}")
    for where, url in actor_urls:
        u = urlparse(url)
        svc = services.get(u.hostname or "")
        if svc is None:
            error(where, f"--learner {url}: no Service {u.hostname}")
            continue
        grpc = [p for p in svc["spec"]["ports"] if p["port"] == u.port]
        if not grpc or grpc[0].get("targetPort") != "grpc":
            error(where, f"--learner {url}: port {u.port} is not the Service's grpc port")
    for secret in sorted(secrets_used):
        if f"create secret generic {secret}" not in readme and secret not in by_kind.get(
            "Secret", {}
        ):
            error("deploy/k8s", f"Secret {secret}: not in the manifests, and the README does "
                                f"not show how to create it")

    # systemd units.
    units = sorted((root / "deploy" / "systemd").glob("*.service"))
    for unit in units:
        for line in unit.read_text().splitlines():
            if line.startswith("ExecStart="):
                words = line.split("=", 1)[1].split()
                if not words or not words[0].endswith("/dvnav"):
                    error(unit.name, "ExecStart does not run dvnav")
                    continue
                check_args(unit.name, words[1:], binary, cache)

    # The Dockerfile.
    docker = (root / "deploy" / "Dockerfile").read_text()
    stages = re.findall(r"^FROM\s+(\S+)(?:\s+AS\s+(\S+))?", docker, re.M | re.I)
    if len(stages) < 2:
        error("deploy/Dockerfile", "not multi-stage")
    elif not re.search(rf"COPY --from={stages[0][1]}\s+\S*dvnav\s", docker):
        error("deploy/Dockerfile", "the last stage does not copy dvnav from the build stage")
    if not re.search(r'^ENTRYPOINT \["[^"]*/dvnav"\]', docker, re.M):
        error("deploy/Dockerfile", "the entrypoint is not the dvnav binary")
    exposed = {int(p) for line in re.findall(r"^EXPOSE (.*)$", docker, re.M)
               for p in line.split()}
    used = {p for _, ports in pod_ports.values() for p in ports.values()}
    for p in sorted(used - exposed):
        error("deploy/Dockerfile", f"port {p} is used by the manifests but not exposed")

    if errors:
        for e in errors:
            print(f"check-deploy: {e}", file=sys.stderr)
        print(f"check-deploy: FAILED ({len(errors)} problems)", file=sys.stderr)
        return 1
    print(f"check-deploy: ok: {len(files)} manifests ({len(objects)} objects), "
          f"{len(units)} systemd units, Dockerfile ({len(stages)} stages); flags checked "
          f"against `dvnav learner/actor --help`, probe paths against {sorted(routed)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
