"""Every command and Python block of README.md and docs/*.md runs, or says why not.

A block of commands (``console``, ``bash``; an indented block whose first word is a
command) or of Python runs in a fresh folder where the repository's ``scripts/``,
``examples/`` and ``tests/`` are linked (``docs/models`` too, the rest of ``docs/``
is not there), in the page's order: ``python scripts/X.py ARGS`` as the script's
``__main__`` does (``main(ARGS)``, in this process: no interpreter start per command;
a ``VAR=value`` prefix is then moot, conftest sets the thread variables), the rest in a
subprocess. An HTML comment just before a block changes that:

- ``<!-- not run: REASON -->``: not run, for the reason given;
- ``<!-- run shortened: SCRIPT ARGS; SCRIPT ARGS -->``: each command of ``SCRIPT`` runs
  with ``ARGS`` appended (argparse takes the last value of a repeated flag);
- ``<!-- run by: TEST -->``: a named test (``tests/...py::name``) or ``.ci/run`` runs it.

The README's two ``    $ `` commands are the ones ``.ci/run`` runs.
"""

from __future__ import annotations

import importlib.util
import inspect
import os
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest
from markdown_it import MarkdownIt

ROOT = Path(__file__).resolve().parents[2]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
SHELL_LANGS = {"console", "bash", "sh", "shell"}
PYTHON_LANGS = {"python", "py"}
TEXT_LANGS = {"text", "yaml", "json", "ini", "toml"}
COMMAND_WORDS = {"python", "python3", "pip", "ray", "tensorboard", "for", "bash", "$", "."}
MARKER = re.compile(r"<!--\s*(not run|run shortened|run by):\s*(.*?)\s*-->", re.S)
LINKED = ("scripts", "examples", "tests", "docs/models")


@dataclass
class Block:
    """One code block of a page."""

    page: Path
    line: int  # 1-based line of the block's first line of code
    kind: str  # "shell", "python" or "text"
    code: str
    marker: tuple[str, str] | None  # (kind, argument) of the comment before it

    def __str__(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"


def _kind(token) -> str:
    if token.type == "fence":
        lang = token.info.strip().split(" ")[0].lower()
        if lang in SHELL_LANGS:
            return "shell"
        if lang in PYTHON_LANGS:
            return "python"
        if lang in TEXT_LANGS:
            return "text"
        raise AssertionError(f"fenced block without a known language: {lang!r}")
    first = token.content.lstrip().split("\n", 1)[0]
    if first.startswith(("from ", "import ")):
        return "python"
    words = first.split()
    if words and all(re.fullmatch(r"[A-Z_]+=\S*", w) for w in words):
        return "shell"  # a variable set for the commands below
    words = [w for w in words if not re.fullmatch(r"[A-Z_]+=\S*", w)]
    return "shell" if words and words[0] in COMMAND_WORDS else "text"


def blocks(page: Path) -> list[Block]:
    """The code blocks of ``page``, each with the marker comment just before it."""
    tokens = MarkdownIt("commonmark").parse(page.read_text())
    out = []
    for i, token in enumerate(tokens):
        if token.type not in ("fence", "code_block"):
            continue
        if token.type == "fence" and token.info.startswith("{"):
            continue  # a MyST directive (toctree, eval-rst), not code
        prev = tokens[i - 1] if i else None
        marker = None
        if prev is not None and prev.type == "html_block":
            match = MARKER.fullmatch(prev.content.strip())
            assert match, f"{page.name}:{prev.map[0] + 1}: unknown comment {prev.content!r}"
            marker = (match.group(1), match.group(2))
        line = token.map[0] + (2 if token.type == "fence" else 1)
        try:
            kind = _kind(token)
        except AssertionError as err:
            raise AssertionError(f"{page.name}:{line}: {err}") from None
        out.append(Block(page, line, kind, token.content, marker))
    return out


def commands(code: str) -> list[list[str]]:
    """The commands of a shell block: continuation lines joined, comments dropped,
    a leading ``$ `` prompt removed."""
    joined = re.sub(r"\\\n\s*", " ", code)
    out = []
    for line in joined.splitlines():
        line = line.strip()
        if line.startswith("$ "):
            line = line[2:]
        words = shlex.split(line, comments=True)
        if words:
            out.append(words)
    return out


def _shortened(argument: str) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for part in argument.split(";"):
        script, *args = shlex.split(part)
        out[script] = args
    return out


def _ci_commands() -> list[str]:
    readme = (ROOT / "README.md").read_text().splitlines()
    return [line[len("    $ "):] for line in readme if line.startswith("    $ ")]


ALL = {page: blocks(page) for page in PAGES}
RUN = [b for page in ALL.values() for b in page if b.kind != "text"]


def _is_ci(block: Block) -> bool:
    return block.page == ROOT / "README.md" and block.code.lstrip().startswith("$ ")


def test_every_block_is_run_or_marked_with_a_reason():
    """Each command or Python block runs here, runs shortened, is run by a named test, or
    says why it is not run; shortened blocks name scripts they hold."""
    counts = {"run": 0, "run shortened": 0, "run by": 0, "not run": 0}
    for block in RUN:
        if _is_ci(block):
            counts["run by"] += 1
            continue
        if block.marker is None:
            counts["run"] += 1
            continue
        kind, argument = block.marker
        counts[kind] += 1
        assert argument, f"{block}: {kind} needs an argument"
        if kind == "run shortened":
            assert block.kind == "shell", f"{block}: only commands can be shortened"
            names = {Path(w).name for cmd in commands(block.code) for w in cmd}
            for script in _shortened(argument):
                assert script in names, f"{block}: {script} is not in the block"
        elif kind == "run by":
            target = argument.split(" ", 1)[0]
            if target == ".ci/run":
                assert (ROOT / ".ci" / "run").is_file()
                continue
            path, _, name = target.partition("::")
            assert f"def {name}(" in (ROOT / path).read_text(), f"{block}: no test {target}"
    print(counts, "of", len(RUN), "blocks")
    assert counts["run"] + counts["run shortened"] >= 30


def test_the_readme_holds_exactly_the_two_commands_ci_runs():
    """``.ci/run`` takes the README's ``    $ `` lines: the install and main job, then
    the tests."""
    first, second = _ci_commands()
    assert "pip install -e" in first and "scripts/evaluate.py" in first
    assert "pytest" in second
    ci = (ROOT / ".ci" / "run").read_text()
    assert ci.count(r"sed -n 's/^    \$ //p' README.md") == 2
    assert "sphinx" in ci and "-W" in ci


def test_text_blocks_hold_no_command():
    """A block of output or a diagram does not start like a command (else it would be
    left out of the run by mistake)."""
    for page in ALL.values():
        for block in page:
            if block.kind == "text":
                first = block.code.lstrip().split("\n", 1)[0]
                assert not re.match(r"(python3? |pip |\$ |[A-Z_]+=)", first), str(block)


def _workdir(tmp_path: Path) -> Path:
    for name in LINKED:
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).symlink_to(ROOT / name)
    return tmp_path


def _run(argv: list[str], cwd: Path, env: dict[str, str], where: Block) -> None:
    result = subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True,
                            timeout=600)
    assert result.returncode == 0, (
        f"{where}: {shlex.join(argv)} exited {result.returncode}\n"
        f"{result.stdout[-2000:]}\n{result.stderr[-4000:]}")


def _run_script(path: str, args: list[str], cwd: Path, where: Block, monkeypatch) -> None:
    """Run ``scripts/...py`` in this process, as its ``__main__`` block does: its ``main``
    with the arguments (one interpreter for the page: no start-up per command)."""
    monkeypatch.chdir(cwd)
    monkeypatch.setattr(sys, "argv", [path, *args])
    spec = importlib.util.spec_from_file_location(f"doc_{Path(path).stem}", ROOT / path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    takes_argv = bool(inspect.signature(module.main).parameters)
    try:
        rc = module.main(args) if takes_argv else module.main()
    except SystemExit as stop:
        rc = stop.code
    assert rc in (0, None) or isinstance(rc, dict), f"{where}: {path} {shlex.join(args)} -> {rc}"


def _run_shell(block: Block, cwd: Path, base_env: dict[str, str], monkeypatch) -> None:
    extra = _shortened(block.marker[1]) if block.marker else {}
    for words in commands(block.code):
        env = dict(base_env)
        while words and re.fullmatch(r"[A-Z_]+=\S*", words[0]):
            key, _, value = words.pop(0).partition("=")
            env[key] = value
        assert words[0] in ("python", "python3"), f"{block}: cannot run {words[0]!r} here"
        script = next((Path(w).name for w in words[1:] if w.endswith(".py")), None)
        args = [*words[1:], *extra.get(script, [])]
        if args[0].startswith("scripts/") and args[0].endswith(".py"):
            _run_script(args[0], args[1:], cwd, block, monkeypatch)
        else:
            _run([sys.executable, *args], cwd, env, block)


# Runs a page's Python blocks in one namespace and fails on an API that its library has
# announced for removal ("... will be removed in v0.13"): documented code must not use it.
RUNNER = """
import runpy, sys, warnings
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    runpy.run_path(sys.argv[1], run_name="__main__")
removed = sorted({str(w.message) for w in caught if " removed in v" in str(w.message)})
if removed:
    sys.exit("uses an API announced for removal: " + removed[0])
"""


def _run_python(blocks_of_page: list[Block], cwd: Path, env: dict[str, str], script: Path):
    """Run the page's Python blocks in order, one namespace (a page's blocks continue
    each other)."""
    script.write_text("".join(f"\n# --- {b}\n{b.code}" for b in blocks_of_page))
    _run([sys.executable, "-c", RUNNER, str(script)], cwd, env, blocks_of_page[0])


def _runnable(page: Path) -> list[Block]:
    return [b for b in ALL[page]
            if b.kind != "text" and not _is_ci(b)
            and (b.marker is None or b.marker[0] == "run shortened")]


@pytest.mark.parametrize("page", [p for p in PAGES if _runnable(p)],
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_page_blocks_run(page, tmp_path, monkeypatch):
    """The page's blocks run (exit status 0), in order, and write nothing into docs/."""
    cwd = _workdir(tmp_path / "work")
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1",
           "MPLBACKEND": "Agg"}
    namespace = tmp_path / "page_blocks.py"
    python_blocks = []
    for block in _runnable(page):
        if block.kind == "shell":
            _run_shell(block, cwd, env, monkeypatch)
        else:
            python_blocks.append(block)
    if python_blocks:
        _run_python(python_blocks, cwd, env, namespace)
    written = [p for p in (cwd / "docs").iterdir() if p.name != "models"]
    assert written == [], f"{page.name}: commands wrote into docs/: {written}"
