#!/usr/bin/env python3
"""The house's layering, checked on the sources (issue 31).

  layers.py SOURCE_ROOT        checks the tree; exit 1 with one line per violation
  layers.py --self-test        proves that each rule fails on a small tree that breaks it

Rules:
  1. core/ folders form a stack (LAYERS below, lowest first): a file includes only its own
     folder or folders below it.
  2. core/ never includes app/ or ui/.
  3. The product door stays apart from the developer tools: ui/ and core/pipeline never include
     core/tools (app/ may: its developer commands are the tools' front end).
  4. No include loop between modules (a module = a folder's X.h, X.cc and private X_impl.h).
"""
import os
import re
import sys
import tempfile

LAYERS = ["util", "io", "render", "model", "train", "face", "morphable", "compose", "pipeline", "tools"]
INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"', re.M)


def sources(root, top):
    base = os.path.join(root, top)
    for folder, _, files in os.walk(base):
        for name in sorted(files):
            if name.endswith((".h", ".cc")):
                path = os.path.join(folder, name)
                yield os.path.relpath(path, root).replace(os.sep, "/")


def includes(root, rel):
    with open(os.path.join(root, rel), encoding="utf-8", errors="replace") as f:
        return INCLUDE.findall(f.read())


def module(rel):
    stem = os.path.splitext(rel)[0]
    # X_impl.h is module X's private header (the state behind X, shared by X's own sources).
    return stem[:-len("_impl")] if stem.endswith("_impl") else stem


def check(root):
    problems = []
    graph = {}
    for top in ("core", "ui", "app"):
        for rel in sources(root, top):
            parts = rel.split("/")
            for inc in includes(root, rel):
                ip = inc.split("/")
                if top == "core":
                    if ip[0] in ("app", "ui"):
                        problems.append(f"{rel}: includes {inc} (core never includes app/ or ui/)")
                    elif ip[0] == "core" and len(ip) > 2 and ip[1] in LAYERS and parts[1] in LAYERS:
                        if LAYERS.index(ip[1]) > LAYERS.index(parts[1]):
                            problems.append(
                                f"{rel}: includes {inc}, but core/{ip[1]} is above core/{parts[1]} "
                                f"(order, lowest first: {' < '.join(LAYERS)})")
                if inc.startswith("core/tools/") and (top == "ui" or rel.startswith("core/pipeline/")):
                    problems.append(f"{rel}: includes {inc} (the product door does not use the developer tools)")
                if inc.endswith(".h") and module(inc) != module(rel) and os.path.exists(os.path.join(root, inc)):
                    graph.setdefault(module(rel), set()).add(module(inc))
    problems += loops(graph)
    return problems


def loops(graph):
    """Tarjan's strongly connected components; every component of two or more modules is a loop."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append("include loop between modules: " + " <-> ".join(sorted(component)))

    sys.setrecursionlimit(10000)
    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def write(root, rel, text):
    path = os.path.join(root, rel)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    with open(path, "w", encoding="utf-8") as f:
        f.write(text)


def self_test():
    cases = {
        "a lower layer includes a higher one": {"core/face/a.cc": '#include "core/morphable/b.h"\n',
                                                "core/morphable/b.h": ""},
        "core includes ui": {"core/util/a.cc": '#include "ui/w.h"\n', "ui/w.h": ""},
        "the door includes a tool": {"core/pipeline/a.cc": '#include "core/tools/t.h"\n', "core/tools/t.h": ""},
        "the GUI includes a tool": {"ui/w.cc": '#include "core/tools/t.h"\n', "core/tools/t.h": ""},
        "a module loop": {"core/pipeline/a.cc": '#include "core/pipeline/b.h"\n',
                          "core/pipeline/a.h": "", "core/pipeline/b.h": '#include "core/pipeline/c.h"\n',
                          "core/pipeline/c.h": "", "core/pipeline/c.cc": '#include "core/pipeline/a.h"\n'},
    }
    clean = {"core/util/a.h": "", "core/pipeline/a.cc": '#include "core/util/a.h"\n#include "core/pipeline/a.h"\n',
             "core/pipeline/a.h": "", "core/tools/t.cc": '#include "core/pipeline/a.h"\n',
             "app/c.cc": '#include "core/tools/t.h"\n', "core/tools/t.h": ""}
    failed = 0
    for name, files in list(cases.items()) + [("a clean tree", clean)]:
        with tempfile.TemporaryDirectory() as root:
            for rel, text in files.items():
                write(root, rel, text)
            problems = check(root)
        expect_fail = name != "a clean tree"
        ok = bool(problems) == expect_fail
        print(f"self-test {'ok' if ok else 'FAILED'}: {name}: {len(problems)} violation(s) {problems[:1]}")
        failed += not ok
    return 1 if failed else 0


def main():
    if len(sys.argv) == 2 and sys.argv[1] == "--self-test":
        return self_test()
    if len(sys.argv) != 2:
        print(__doc__)
        return 2
    problems = check(sys.argv[1])
    for p in problems:
        print("FAIL:", p)
    if problems:
        return 1
    print(f"OK: core layers {' < '.join(LAYERS)}; ui/ and core/pipeline use no core/tools; no module include loops")
    return 0


if __name__ == "__main__":
    sys.exit(main())
