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
            out.add(base)
            out.update(f"{base}.{a.name}" for a in node.names if f"{base}.{a.name}" in modules)
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
