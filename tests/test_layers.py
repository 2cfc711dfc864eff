"""The packages' layering: the language (asap_dsl with stl and sim) below the backends (oracle, rl,
compare) below the command line (asap_dsl.cli), and nothing imported against that order.

Each package is imported alone in a fresh interpreter that records every import made while
modules execute; what the interpreter holds afterwards (``sys.modules``) and the edges recorded
are checked. Imports inside functions (the lazy public names of ``asap_dsl``, ``lint --deep``
asking the oracle) run on use, not on import, and are allowed; the one exception is the command
line, which nothing but its entry points may import at all (checked in the source).
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys

import pytest

from conftest import ROOT

PACKAGES = ["asap_dsl", "asap_dsl.stl", "asap_dsl.sim", "asap_dsl.backends.oracle", "asap_dsl.backends.rl",
            "asap_dsl.backends.compare", "asap_dsl.cli"]

# Records (importer, imported) for every asap_dsl module imported while an asap_dsl module runs,
# then imports the modules named on its command line, in order.
_PROBE = r"""
import builtins, importlib, importlib.util, json, sys
edges = set()
_import = builtins.__import__

def record(name, globals=None, locals=None, fromlist=(), level=0):
    module = _import(name, globals, locals, fromlist, level)
    importer = (globals or {}).get("__name__", "")
    if importer.startswith("asap_dsl"):
        base = importlib.util.resolve_name("." * level + name, globals.get("__package__") or importer) if level else name
        for target in [base] + [f"{base}.{f}" for f in fromlist or () if isinstance(f, str)]:
            if target.startswith("asap_dsl") and target in sys.modules:
                edges.add((importer, target))
    return module

builtins.__import__ = record
for name in sys.argv[1:]:
    module = importlib.import_module(name)
    if name == "asap_dsl.cli":
        module.build_parser()  # every command's flags
print(json.dumps({"edges": sorted(edges), "modules": sorted(m for m in sys.modules if m.split(".")[0] in
                  ("asap_dsl", "torch", "stable_baselines3", "jax", "casadi"))}))
"""


def _probe(*modules: str) -> tuple[set[tuple[str, str]], set[str]]:
    """The import edges between asap_dsl modules, and the modules loaded, after importing
    ``modules`` in a fresh interpreter."""
    proc = subprocess.run([sys.executable, "-c", _PROBE, *modules], cwd=ROOT, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    data = json.loads(proc.stdout.strip().splitlines()[-1])
    return {tuple(e) for e in data["edges"]}, set(data["modules"])


def layer(module: str) -> str:
    """The layer of a module: ``language`` (asap_dsl and its stl, sim and grammar, which use each
    other: an atom of a formula is an expression, a simulator steps a system model), one per
    backend package, ``cli``."""
    parts = module.split(".")
    if parts[1:2] == ["backends"]:
        return ".".join(parts[1:3])
    if parts[1:2] == ["cli"]:
        return "cli"
    return "language"


#: The layers, lowest first: a module imports (when it loads) only from its own layer or below,
#: so there is no cycle between them.
ORDER = ["language", "backends", "backends.oracle", "backends.rl", "backends.compare", "cli"]


def _language_modules(package: str) -> list[str]:
    """``package`` and every module below it in the source tree (none of the CLI)."""
    folder = ROOT.joinpath(*package.split("."))
    names = [package]
    for path in sorted(folder.rglob("*.py")):
        rel = path.relative_to(ROOT).with_suffix("").parts
        if "cli" in rel or rel[-1] in ("__init__", "__main__"):
            continue
        names.append(".".join(rel))
    return names


@pytest.mark.parametrize("package", PACKAGES)
def test_each_package_imports_alone_and_only_downwards(package):
    language = layer(package) == "language"
    edges, modules = _probe(*(_language_modules(package) if language else [package]))
    if package != "asap_dsl.cli":
        assert not [m for m in modules if m.startswith("asap_dsl.cli")], "only asapc's entry points import the CLI"
    if language:
        assert not [m for m in modules if m.startswith("asap_dsl.backends")], \
            "the language imports no backend when it loads (only asap_dsl's lazy names, on use)"
    unknown = {layer(m) for edge in edges for m in edge} - set(ORDER)
    assert not unknown, f"a new package: give {sorted(unknown)} its place in ORDER"
    upward = sorted((a, b) for a, b in edges if ORDER.index(layer(b)) > ORDER.index(layer(a)))
    assert not upward, f"imports against the layers (a cycle in the making): {upward}"


def test_the_command_line_builds_its_parser_without_torch_or_jax():
    _, modules = _probe("asap_dsl.cli")
    assert not {"torch", "stable_baselines3", "jax"} & modules, "asapc lint must not wait for torch or jax"


def _imports(path) -> list[tuple[str, bool]]:
    """Every module a source file imports (relative imports resolved), and whether at module level."""
    rel = path.relative_to(ROOT)
    parts = list(rel.with_suffix("").parts)
    if parts[0] == "backends":
        parts = ["asap_dsl"] + parts
    package = parts[:-1]  # of a module, and of a package's __init__ alike
    tree = ast.parse(path.read_text(encoding="utf-8"))
    top = set(map(id, tree.body))
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(a.name, id(node) in top) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = package[:len(package) - node.level + 1] if node.level else []
            name = ".".join(base + ([node.module] if node.module else [])) if node.level else node.module or ""
            out += [(name, id(node) in top)] + [(f"{name}.{a.name}", id(node) in top) for a in node.names]
    return out


def test_nothing_but_the_entry_points_imports_the_command_line():
    sources = [p for d in ("asap_dsl", "backends") for p in (ROOT / d).rglob("*.py")
               if "cli" not in p.relative_to(ROOT).parts]
    assert sources
    bad = [(str(p.relative_to(ROOT)), name) for p in sources for name, _ in _imports(p)
           if name == "asap_dsl.cli" or name.startswith("asap_dsl.cli.")]
    assert not bad, bad
    assert not [str(p) for p in (ROOT / "backends").rglob("*.py") if "argparse" in {n for n, _ in _imports(p)}], \
        "no backend parses arguments"
