"""The README's Python example runs, against a real daemon."""

from __future__ import annotations

import pathlib
import re
import runpy

from ftafm.testing import Daemon

ROOT = pathlib.Path(__file__).resolve().parents[2]


def python_blocks(path: pathlib.Path) -> list[str]:
    return re.findall(r"```python\n(.*?)```", path.read_text(), flags=re.S)


def test_the_readme_example_runs(ftafm_daemon: Daemon, tmp_path, capsys, monkeypatch) -> None:
    blocks = [b for b in python_blocks(ROOT / "README.md") if "import ftafm" in b]
    assert blocks, "README.md has a Python example that uses the package"
    for block in blocks + [b for b in python_blocks(ROOT / "docs" / "python.md")
                           if "# run-in-test" in b]:
        script = tmp_path / "example.py"
        script.write_text(block.replace("ws://127.0.0.1:8700/ws", ftafm_daemon.url))
        monkeypatch.chdir(tmp_path)
        runpy.run_path(str(script), run_name="__main__")
    out = capsys.readouterr().out
    assert re.search(r"H17 = \d+\.\d\d pm over \d+ frames, 0 lost", out), out
