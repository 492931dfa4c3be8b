"""The runtime never imports torch: every svbrdf_cli module, every --help, in a fresh interpreter."""

import subprocess
import sys

from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

SCRIPT = r"""
import importlib, pkgutil, sys
import svbrdf_cli
names = ['svbrdf_cli'] + [m.name for m in pkgutil.walk_packages(svbrdf_cli.__path__, 'svbrdf_cli.')]
for name in names:
    importlib.import_module(name)
from click.testing import CliRunner
from svbrdf_cli.cli.main import cli
runner = CliRunner()
helps = [[]] + [[name] for name in cli.commands]
for args in helps:
    res = runner.invoke(cli, args + ['--help'])
    assert res.exit_code == 0, (args, res.output)
bad = sorted(m for m in sys.modules if m == 'torch' or m.startswith('torch.'))
print(len(names), 'modules', len(helps), 'helps')
assert not bad, bad
"""


def test_runtime_never_imports_torch():
    res = subprocess.run([sys.executable, "-c", SCRIPT], cwd=ROOT, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr + res.stdout
    assert "modules" in res.stdout
