#!/usr/bin/env python3
"""Checks that each crate's module graph has no cycles.

Usage: module_cycles.py SRC_DIR [SRC_DIR ...]   (each a crate's `src`, holding lib.rs)

A module is a file, with the modules nested in it. Module A depends on module B where code in A (not comments)
names B's path, or an item in it, through `crate::`, `super::` or `self::`: then, of the two modules under
their common parent, the one holding A depends on the one holding B. A parent re-exporting its children's
items, or a child using its parent's, is containment, not a dependency.
Exits 1 and prints each cycle where there is one.
"""

import re
import sys
from pathlib import Path

PATH = re.compile(r"\b(crate|super|self)((?:::[A-Za-z_][A-Za-z0-9_]*)*)(::\{[^;]*?\})?", re.S)


def module_path(src: Path, file: Path) -> tuple:
    parts = list(file.relative_to(src).with_suffix("").parts)
    if parts[-1] in ("mod", "lib", "main"):
        parts.pop()
    return tuple(parts)


def code_of(text: str) -> str:
    lines = []
    for line in text.splitlines():
        stripped = line.lstrip()
        if stripped.startswith("//"):
            continue
        lines.append(line.split(" // ", 1)[0])
    return "\n".join(lines)


def group_paths(group: str):
    """The paths named in a `{a, b::c, d::{e, f}}` group, relative to the group's base (first level only)."""
    inner = group[group.index("{") + 1 : group.rindex("}")]
    depth, current, names = 0, "", []
    for char in inner:
        if char == "{":
            depth += 1
        elif char == "}":
            depth -= 1
        if char == "," and depth == 0:
            names.append(current)
            current = ""
        else:
            current += char
    names.append(current)
    for name in names:
        name = name.strip().split("{")[0].strip(": ")
        if name and name != "self":
            yield tuple(name.split("::"))


def resolve(modules: set, base: tuple, names: tuple) -> tuple:
    """The deepest module that `base` + `names` reaches."""
    path = base
    for name in names:
        if path + (name,) in modules:
            path = path + (name,)
        else:
            break
    return path


def edges_of(src: Path, modules: set, file: Path):
    here = module_path(src, file)
    for match in PATH.finditer(code_of(file.read_text())):
        root, rest, group = match.group(1), match.group(2), match.group(3)
        if not rest and not group:
            continue  # `self` as a value or a bare `super`/`crate`: no path.
        names = tuple(name for name in rest.strip(":").split("::") if name)
        base = {"crate": (), "self": here, "super": here[:-1]}[root]
        while names and names[0] == "super":
            base, names = base[:-1], names[1:]
        targets = [resolve(modules, base, names)]
        if group:
            start = resolve(modules, base, names)
            targets = [resolve(modules, start, inner) for inner in group_paths(group)]
        for target in targets:
            nested = target[: len(here)] == here or here[: len(target)] == target
            if not nested:
                # Between the two siblings, under the modules' common parent, that hold them.
                common = 0
                while here[common] == target[common]:
                    common += 1
                yield here[: common + 1], target[: common + 1]


def cycles(graph: dict) -> list:
    found, state = [], {}

    def visit(node, stack):
        state[node] = "open"
        stack.append(node)
        for next_node in sorted(graph.get(node, ())):
            if state.get(next_node) == "open":
                found.append(stack[stack.index(next_node) :] + [next_node])
            elif next_node not in state:
                visit(next_node, stack)
        stack.pop()
        state[node] = "done"

    for node in sorted(graph):
        if node not in state:
            visit(node, [])
    return found


def main() -> int:
    failed = False
    for arg in sys.argv[1:]:
        src = Path(arg)
        files = sorted(src.rglob("*.rs"))
        modules = {module_path(src, file) for file in files}
        graph = {}
        for file in files:
            for here, target in edges_of(src, modules, file):
                graph.setdefault(here, set()).add(target)
        for cycle in cycles(graph):
            failed = True
            print(f"{src}: module cycle: " + " -> ".join("::".join(m) or "crate" for m in cycle))
    if not failed:
        print(f"no module cycles in {len(sys.argv) - 1} crates")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
