"""The command examples in README.md and docs/*.md name commands, options and modules that exist.

Code blocks and inline code are scanned for ``svbrdf <command> ...`` (checked against the click
group :data:`svbrdf_cli.cli.main.cli`: the command, and every ``--option`` / ``-x`` after it, on the
command or the group; hidden aliases do not count as documented) and for ``python -m <module>``
(the module must be found by :func:`importlib.util.find_spec`; nothing is run) and
``python <script>.py`` (the script must exist).
"""

from __future__ import annotations

import importlib.util
import os
import re
import shlex
from pathlib import Path

import click
import pytest

from svbrdf_cli.cli.main import cli

ROOT = Path(__file__).resolve().parent.parent
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]

_FENCE = re.compile(r"^\s*(```|~~~)")
_INLINE = re.compile(r"`([^`]+)`")
_OPTION = re.compile(r"^-{1,2}[A-Za-z][\w-]*")
_COMMAND = re.compile(r"^[a-z][a-z0-9_-]*$")
_SEPARATORS = re.compile(r"&&|\|\||[;|]")
_PYTHON = re.compile(r"^python(\d+(\.\d+)?)?$")
_COMMENT = re.compile(r"\s#(\s|$)")


def code_snippets(path):
    """(line number, code) for every line of a fenced block (comments stripped; their inline code
    kept as snippets of their own) and every inline code span outside the blocks."""
    out, prose, fenced = [], [], False
    for no, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if _FENCE.match(line):
            fenced = not fenced
            prose.append("")
            continue
        if not fenced:
            prose.append(line)
            continue
        prose.append("")
        m = _COMMENT.search(line)
        code, comment = (line[:m.start()], line[m.end():]) if m else (line, "")
        out.append((no, code.strip().removeprefix("$ ")))
        out += [(no, m.group(1)) for m in _INLINE.finditer(comment)]
    text = "\n".join(prose)  # fenced lines blanked: the same line numbers, spans may cross lines
    out += [(text.count("\n", 0, m.start()) + 1, " ".join(m.group(1).split())) for m in _INLINE.finditer(text)]
    return sorted(out)


def _tokens(command):
    try:
        return shlex.split(command)
    except ValueError:  # an unbalanced quote in prose-like code: plain words are enough here
        return command.split()


def _names(params):
    """Visible and hidden option names of click ``params``."""
    visible, hidden = set(), set()
    for p in params:
        if isinstance(p, click.Option):
            (hidden if p.hidden else visible).update(p.opts + p.secondary_opts)
    return visible, hidden


def check_svbrdf(words):
    """Problems with one ``svbrdf ...`` invocation (the words after ``svbrdf``)."""
    group_visible, group_hidden = _names(cli.params)
    group_visible |= set(cli.context_settings.get("help_option_names", ["--help"]))
    problems, command, visible, hidden = [], None, group_visible, group_hidden
    for w in words:
        w = w.strip("[](),")
        opt = _OPTION.match(w)
        if opt:
            name = opt.group(0)
            if name in hidden:
                problems.append(f"{name} is a hidden alias of {'svbrdf ' + command if command else 'svbrdf'}: "
                                "document the visible option")
            elif name not in visible:
                problems.append(f"no option {name} on {'svbrdf ' + command if command else 'svbrdf'}")
        elif command is None:
            if not _COMMAND.match(w):  # a placeholder (COMMAND), '…': nothing to check
                return problems
            if w not in cli.commands:
                return problems + [f"no command 'svbrdf {w}' (commands: {', '.join(sorted(cli.commands))})"]
            command = w
            cmd_visible, cmd_hidden = _names(cli.commands[w].params)
            visible, hidden = group_visible | cmd_visible, (group_hidden | cmd_hidden) - cmd_visible
    return problems


def check_python(words):
    """Problems with one ``python ...`` invocation (the words after ``python``)."""
    if words[:1] == ["-m"] and len(words) > 1:
        module = words[1]
        try:
            spec = importlib.util.find_spec(module)
            if spec is not None and spec.submodule_search_locations is not None:  # a package: its __main__
                spec = importlib.util.find_spec(module + ".__main__")
        except ImportError as e:
            return [f"python -m {module}: {e}"]
        return [] if spec is not None else [f"python -m {module}: no such module"]
    if words and words[0].endswith(".py") and not (ROOT / words[0]).is_file():
        return [f"python {words[0]}: no such script"]
    return []


def problems(code):
    """Problems of every ``svbrdf`` and ``python`` invocation in one snippet."""
    out = []
    for part in _SEPARATORS.split(code):
        words = _tokens(part)
        for i, w in enumerate(words):
            base = os.path.basename(w)
            if base == "svbrdf":
                out += check_svbrdf(words[i + 1:])
                break
            if _PYTHON.match(base):
                out += check_python(words[i + 1:])
                break
    return out


def test_the_checker_finds_what_is_wrong():
    assert problems("svbrdf capture photo.jpg -o out --model auto --size 2048") == []
    assert problems(".venv/bin/svbrdf -v batch shoot/ -o s3://b/t --engine ray && svbrdf --version") == []
    assert problems("svbrdf COMMAND --help") == [] and problems("svbrdf[scale]") == []
    assert problems("svbrdf capture photo.jpg --no-such-option") == ["no option --no-such-option on svbrdf capture"]
    assert problems("svbrdf frobnicate x") and problems("svbrdf render set -x")
    assert problems("python -m export.train --stage all") == [] and problems("python3 -m venv .venv") == []
    assert problems("python -m export.data throughput") == []  # a package run through its __main__
    assert problems(".venv/bin/python -m export.no_such_module") == ["python -m export.no_such_module: no such module"]
    assert problems("python -m export.render") == ["python -m export.render: no such module"]  # no __main__
    assert problems("python tests/data/make_brdf_golden.py") == [] and problems("python tests/nothing.py")


def test_snippets_come_from_blocks_comments_and_inline_code(tmp_path):
    doc = tmp_path / "doc.md"
    doc.write_text("Run `svbrdf capture\nx.jpg --size 512` now.\n\n```bash\nsvbrdf batch in -o out   "
                   "# see `svbrdf markers m.png`\n```\n", encoding="utf-8")
    assert code_snippets(doc) == [(1, "svbrdf capture x.jpg --size 512"), (5, "svbrdf batch in -o out"),
                                  (5, "svbrdf markers m.png")]


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_documented_commands_exist(doc):
    bad = [f"{doc.relative_to(ROOT)}:{no}: {code!r}: {p}" for no, code in code_snippets(doc) for p in problems(code)]
    assert not bad, "documented commands that do not exist:\n" + "\n".join(bad)


def _documented():
    """Every ``svbrdf`` command the docs show (with its options), every option they name, and every
    ``python -m`` module."""
    commands, options, modules = {}, set(), set()
    for doc in DOCS:
        for _, code in code_snippets(doc):
            for part in _SEPARATORS.split(code):
                words = _tokens(part)
                options.update(_OPTION.match(w).group(0) for w in words if _OPTION.match(w))
                names = [w.rpartition("/")[2] for w in words]
                if "svbrdf" in names:
                    rest = [w for w in words[names.index("svbrdf") + 1:]]
                    cmd = next((w for w in rest if _COMMAND.match(w)), None)
                    if cmd:
                        commands.setdefault(cmd, set()).update(_OPTION.match(w).group(0) for w in rest
                                                                if _OPTION.match(w))
                if "-m" in words and words.index("-m") + 1 < len(words):
                    modules.add(words[words.index("-m") + 1])
    return commands, options, modules


def test_every_command_and_option_is_documented():
    commands, options, _ = _documented()
    missing = []
    for name, cmd in [(None, cli), *cli.commands.items()]:
        if name is not None and name not in commands:
            missing.append(f"svbrdf {name}")
        for p in cmd.params:
            if isinstance(p, click.Option) and not p.hidden and not set(p.opts) & options:
                missing.append(f"svbrdf {name or ''} {'/'.join(p.opts)}")
    assert not missing, "commands and options no doc shows (README.md, docs/*.md):\n" + "\n".join(missing)


def test_every_runnable_module_is_documented():
    _, _, modules = _documented()
    runnable = set()
    for path in sorted((ROOT / "export").rglob("*.py")):
        text = path.read_text(encoding="utf-8")
        name = ".".join(path.relative_to(ROOT).with_suffix("").parts)
        if path.name == "__main__.py":
            runnable.add(name.rpartition(".")[0])
        elif 'if __name__ == "__main__"' in text:
            runnable.add(name)
    missing = sorted(runnable - modules)
    assert not missing, "python -m modules no doc shows how to run:\n" + "\n".join(missing)


def test_readme_top_commands_are_what_ci_runs_and_say_what_they_cost():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    blocks = re.findall(r"```bash\n(.*?)\n```", readme, re.S)
    run_cmd, test_cmd = blocks[0].strip(), blocks[1].strip()
    assert "svbrdf capture examples/glazed_tiles.jpg" in run_cmd and "pip install ." in run_cmd
    # the test command's steps, in .ci/run's order
    steps = [s.strip().replace(".venv/bin/", "") for s in test_cmd.split("&&")]
    assert steps[-1] == "python -m pytest -q" and ".venv/bin/python -m pytest -q" in ci
    for step in steps[1:-1]:
        assert step.removeprefix("pip install ").strip() in ci, step
    top = readme[: readme.index("## Using it")]
    assert "about 20 minutes" in top and "2 GB" in top
    assert "--index-url https://download.pytorch.org/whl/cpu" in top  # the CPU build elsewhere
    status = readme[readme.index("## Status"): readme.index("## Method")]
    assert "without the flash spot" not in status and "docs/benchmarks.md" in status
