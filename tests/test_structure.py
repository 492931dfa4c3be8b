"""The package's shape: the CLI is a thin shell over the library, and no two modules import each other.

Imports are read from the source (every ``import``, at module level or inside a function), so a
lazy import that closes a cycle counts too.
"""

import ast
import os

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PACKAGES = ("svbrdf_cli", "export")


def _modules():
    """{dotted module name: path} of every module of our packages."""
    found = {}
    for pkg in PACKAGES:
        for d, _, names in os.walk(os.path.join(ROOT, pkg)):
            for n in names:
                if n.endswith(".py"):
                    rel = os.path.relpath(os.path.join(d, n), ROOT)[:-3].replace(os.sep, ".")
                    found[rel[: -len(".__init__")] if rel.endswith(".__init__") else rel] = os.path.join(d, n)
    return found


def _imports(path, name, modules):
    """Dotted names ``path`` imports (absolute, resolved to our modules where they are ours)."""
    out = set()
    package = name if path.endswith("__init__.py") else name.rpartition(".")[0]
    with open(path, encoding="utf-8") as f:
        tree = ast.parse(f.read())
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(parts + ([base] if base else []))
            subs = {f"{base}.{a.name}" for a in node.names if f"{base}.{a.name}" in modules}
            out.update(subs)
            if len(subs) < len(node.names):  # names of the module itself, not only its submodules
                out.add(base)
    return out


def _graph():
    modules = _modules()
    return {m: {i for i in _imports(p, m, modules) if i in modules and i != m} for m, p in modules.items()}, modules


def test_the_library_never_imports_the_cli_or_click():
    graph, modules = _graph()
    offenders = []
    for m, path in modules.items():
        if not m.startswith("svbrdf_cli.") or m.startswith("svbrdf_cli.cli"):
            continue
        raw = _imports(path, m, modules)
        bad = sorted(i for i in raw if i == "click" or i.startswith("click.") or i.startswith("svbrdf_cli.cli"))
        if bad:
            offenders.append(f"{m}: {', '.join(bad)}")
    assert not offenders, "library modules importing the CLI or click:\n" + "\n".join(offenders)


def test_no_import_cycles():
    graph, _ = _graph()
    state, stack, cycles = {}, [], []

    def visit(m):
        state[m] = 1
        stack.append(m)
        for d in sorted(graph[m]):
            if state.get(d) == 1:
                cycles.append(" -> ".join(stack[stack.index(d):] + [d]))
            elif d not in state:
                visit(d)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)
    assert not cycles, "import cycles:\n" + "\n".join(cycles)


def test_each_command_has_its_module_and_tests_and_cli_modules_stay_small():
    from svbrdf_cli.cli.main import cli

    cli_dir = os.path.join(ROOT, "svbrdf_cli", "cli")
    for name, cmd in cli.commands.items():
        module = cmd.callback.__module__.rpartition(".")[2]
        assert module in (name, f"{name}_set"), f"'svbrdf {name}' lives in {cmd.callback.__module__}"
        assert os.path.isfile(os.path.join(ROOT, "tests", "runtime", "cli", f"test_{name}.py")), name
    sizes = {}
    for n in os.listdir(cli_dir):
        if n.endswith(".py"):
            with open(os.path.join(cli_dir, n)) as f:
                sizes[n] = len(f.read().splitlines())
    assert max(sizes.values()) < 150, sizes


#: The runtime's stages in the order a capture runs them; a module may import its own stage and the
#: ones before it, never one after (``base``: the top-level modules every stage uses).
STAGES = ("base", "ingest", "rectify", "infer", "write", "run", "cli", "entry")
#: The most top-level modules ``svbrdf_cli`` may have (besides its stage packages).
MAX_TOP_MODULES = 8


def _stage(module):
    """The stage of a ``svbrdf_cli`` module (``entry``: the package itself, the public library entry)."""
    parts = module.split(".")
    if len(parts) == 1:
        return "entry"
    return parts[1] if parts[1] in STAGES and len(parts) > 2 or parts[1] in STAGES[1:7] and len(parts) == 2 \
        and os.path.isdir(os.path.join(ROOT, *parts)) else "base"


def test_the_runtime_has_its_stage_packages_and_few_top_level_modules():
    top = sorted(n for n in os.listdir(os.path.join(ROOT, "svbrdf_cli")) if n.endswith(".py"))
    assert len(top) <= MAX_TOP_MODULES, top
    for stage in STAGES[1:7]:
        assert os.path.isfile(os.path.join(ROOT, "svbrdf_cli", stage, "__init__.py")), stage


def test_no_import_runs_back_up_the_stages():
    graph, _ = _graph()
    bad = []
    for m, deps in graph.items():
        if not m.startswith("svbrdf_cli"):
            continue
        for d in deps:
            if not d.startswith("svbrdf_cli"):
                continue
            if STAGES.index(_stage(d)) > STAGES.index(_stage(m)):
                bad.append(f"{m} ({_stage(m)}) imports {d} ({_stage(d)})")
    assert not bad, "imports that run back up the stages:\n" + "\n".join(sorted(bad))


def test_the_runtime_never_imports_the_training_package_nor_training_its_studies():
    graph, _ = _graph()
    bad = [f"{m} imports {d}" for m, deps in graph.items() for d in deps
           if (m.startswith("svbrdf_cli") and d.startswith("export"))
           or (m.startswith("export") and not m.startswith("export.studies") and d.startswith("export.studies"))]
    assert not bad, "\n".join(sorted(bad))


def _private_uses(path, modules):
    """``module._name`` and ``from module import _name`` of our modules in one file."""
    with open(path, encoding="utf-8") as f:
        tree = ast.parse(f.read())
    aliases, found = {}, []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] in PACKAGES:
            for a in node.names:
                full = f"{node.module}.{a.name}"
                if full in modules:
                    aliases[a.asname or a.name] = full
                elif a.name.startswith("_") and not a.name.startswith("__"):
                    found.append(f"from {node.module} import {a.name}")
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name in modules and a.asname:
                    aliases[a.asname] = a.name
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in aliases
                and node.attr.startswith("_") and not node.attr.startswith("__")):
            found.append(f"{aliases[node.value.id]}.{node.attr}")
    return found


def test_no_module_uses_another_modules_private_names():
    _, modules = _graph()
    bad = [f"{m}: {u}" for m, p in modules.items() for u in _private_uses(p, modules)]
    assert not bad, "private names used across modules:\n" + "\n".join(sorted(bad))


def test_the_runtime_wheel_holds_the_runtime_and_no_torch():
    """``pip install .`` installs the packages pyproject's ``packages.find`` names: ``svbrdf_cli``'s
    alone, none of whose modules imports torch (the training package runs from a checkout)."""
    import fnmatch
    import re

    from setuptools import find_packages

    with open(os.path.join(ROOT, "pyproject.toml"), encoding="utf-8") as f:
        text = f.read()
    include = re.search(r"\[tool\.setuptools\.packages\.find\][^\[]*?include\s*=\s*\[([^\]]*)\]", text, re.S)
    patterns = re.findall(r'"([^"]+)"', include.group(1))
    packages = [p for p in find_packages(ROOT) if any(fnmatch.fnmatch(p, pat) for pat in patterns)]
    assert packages and all(p == "svbrdf_cli" or p.startswith("svbrdf_cli.") for p in packages), packages
    _, modules = _graph()
    torch_users = [m for m, path in modules.items() if m.rpartition(".")[0] in packages or m in packages
                   for i in _imports(path, m, modules) if i == "torch" or i.startswith("torch.")]
    assert not torch_users, torch_users
