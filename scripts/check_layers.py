#!/usr/bin/env python3
"""The workspace's structure rules, checked from the sources (`make lint`).

1. Crate layering: each crate depends only on the dvnav crates its layer allows (the simulator on
   nothing of ours, the agent on the simulator and the config, ...), and no crate under common/
   depends on the actor or the learner.
2. No import loops: inside every crate, no module refers to a module that refers back to it,
   directly or through others. Parents and their own submodules are exempt (a parent declares
   and re-exports its children; a child may use its parent's items), and test code is skipped.

Prints each violation and exits 1; prints a one-line summary and exits 0 when all hold.
"""

import re
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

# The dvnav crates each crate may depend on ([dependencies] and [dev-dependencies]).
ALLOWED = {
    "dvnav-proto": set(),
    "dvnav-sim": set(),
    "dvnav-config": {"dvnav-sim"},
    "dvnav-nav": {"dvnav-sim", "dvnav-config"},
    "dvnav-link": {"dvnav-sim", "dvnav-proto"},
    "dvnav-eval": {"dvnav-sim", "dvnav-config", "dvnav-nav", "dvnav-link", "dvnav-proto"},
    "dvnav-tls": set(),
    "dvnav-render": {"dvnav-sim", "dvnav-nav"},
    "dvnav-python": {"dvnav-sim", "dvnav-config", "dvnav-nav", "dvnav-render"},
    "dvnav-actor": {"dvnav-sim", "dvnav-config", "dvnav-nav", "dvnav-link", "dvnav-eval",
                    "dvnav-tls", "dvnav-proto"},
    "dvnav-learner": {"dvnav-sim", "dvnav-config", "dvnav-nav", "dvnav-link", "dvnav-eval",
                      "dvnav-tls", "dvnav-proto"},
}


def members():
    ws = tomllib.loads((ROOT / "Cargo.toml").read_text())
    dirs = [ROOT / m for m in ws["workspace"]["members"]] + [ROOT]
    for d in dirs:
        manifest = tomllib.loads((d / "Cargo.toml").read_text())
        if "package" in manifest:
            yield d, manifest


def check_layers(errors):
    for d, manifest in members():
        name = manifest["package"]["name"]
        deps = set()
        for section in ("dependencies", "dev-dependencies", "build-dependencies"):
            deps |= {k for k in manifest.get(section, {}) if k.startswith("dvnav-")}
        if name not in ALLOWED:
            if d != ROOT:
                errors.append(f"{d.relative_to(ROOT)}: crate {name} has no layer in "
                              "scripts/check_layers.py ALLOWED; add it there")
            continue
        for dep in sorted(deps - ALLOWED[name]):
            errors.append(f"{d.relative_to(ROOT)}/Cargo.toml: {name} must not depend on {dep}")


def module_path(src: Path, f: Path):
    parts = list(f.relative_to(src).with_suffix("").parts)
    if parts[-1] in ("lib", "main", "mod"):
        parts = parts[:-1]
    return tuple(parts)


def strip_tests(text: str) -> str:
    """Code before the first `#[cfg(test)]` (test modules come last in our files)."""
    return text.split("#[cfg(test)]", 1)[0]


USE_RE = re.compile(r"\bpub(?:\([a-z]+\))?\s+use\s+([\w:]+)::(\{[^;]*\}|\w+)(?:\s+as\s+\w+)?;", re.S)
REF_RE = re.compile(r"\b(crate|super)((?:::\w+)+)")


def crate_graph(src: Path):
    files = {}
    for f in sorted(src.rglob("*.rs")):
        if f.name == "tests.rs" or "tests" in f.relative_to(src).parts[:-1]:
            continue
        files[module_path(src, f)] = strip_tests(f.read_text())
    modules = set(files)
    # Re-exports: (module, name) -> module the item is defined in.
    reexport = {}
    for m, text in files.items():
        for base, names in USE_RE.findall(text):
            segs = base.split("::")
            if segs[0] == "crate":
                target = tuple(segs[1:])
            elif segs[0] in ("self",):
                target = m + tuple(segs[1:])
            elif segs[0] == "super":
                target = m[:-1] + tuple(segs[1:])
            else:
                target = m + tuple(segs)
            for n in re.findall(r"\w+", names):
                reexport[(m, n)] = target

    def resolve(segs):
        # Longest prefix that is a module, then follow a re-export of the next name.
        for k in range(len(segs), -1, -1):
            if tuple(segs[:k]) in modules:
                mod = tuple(segs[:k])
                if k < len(segs) and (mod, segs[k]) in reexport:
                    tgt = reexport[(mod, segs[k])]
                    return tgt if tgt in modules else mod
                return mod
        return ()

    edges = {m: set() for m in modules}
    for m, text in files.items():
        code = "\n".join(l for l in text.split("\n") if not l.lstrip().startswith("//"))
        for head, rest in REF_RE.findall(code):
            segs = rest.split("::")[1:]
            if head == "crate":
                target = resolve(segs)
            else:
                base = list(m[:-1])
                while segs and segs[0] == "super":
                    base, segs = base[:-1], segs[1:]
                target = resolve(base + segs)
            related = target[: len(m)] == m or m[: len(target)] == target
            if not related:
                edges[m].add(target)
        # `use crate::a::{b, c}` names several modules at once.
        for base, names in re.findall(r"\buse\s+crate::([\w:]*)::\{([^;]*)\};", code, re.S):
            for n in re.findall(r"(\w+)(?:::|\s*[,}]|$)", names):
                target = resolve(base.split("::") + [n])
                if not (target[: len(m)] == m or m[: len(target)] == target):
                    edges[m].add(target)
    return edges


def find_cycle(edges):
    state, stack = {}, []

    def visit(n):
        state[n] = 1
        stack.append(n)
        for t in sorted(edges.get(n, ())):
            if state.get(t) == 1:
                return stack[stack.index(t):] + [t]
            if t not in state:
                c = visit(t)
                if c:
                    return c
        stack.pop()
        state[n] = 2
        return None

    for n in sorted(edges):
        if n not in state:
            c = visit(n)
            if c:
                return c
    return None


def check_loops(errors):
    count = 0
    for d, manifest in members():
        src = d / "src"
        if not src.is_dir():
            continue
        edges = crate_graph(src)
        count += len(edges)
        # Report every loop: break each found one at its first edge and look again.
        while True:
            cycle = find_cycle(edges)
            if not cycle:
                break
            names = [("crate::" + "::".join(m)) if m else "crate" for m in cycle]
            errors.append(f"{manifest['package']['name']}: import loop " + " -> ".join(names))
            edges[cycle[0]].discard(cycle[1])
    return count


def main():
    errors = []
    check_layers(errors)
    modules = check_loops(errors)
    for e in errors:
        print(f"check_layers: {e}")
    if errors:
        return 1
    print(f"check_layers: crate layering holds; no import loop among {modules} modules")
    return 0


if __name__ == "__main__":
    sys.exit(main())
