"""The README and docs/ as a reader meets them: every page is reachable from the README, every relative link
and anchor resolves, the commands marked runnable run, and no ``--help`` shows reStructuredText markup.

A block is runnable when the line before its opening fence is ``<!-- runnable -->`` (or ``<!-- runnable:
output -->``) and the fence's language is ``console``: each line starting with ``$ `` is one command, run in
order in one temporary directory per block that holds links to the repository's ``config/`` and ``bags/``,
with the interpreter's ``bin/`` first on ``PATH`` (the console scripts ``gap-validate`` and ``validator_node``
are there). Each must exit 0. With ``runnable: output`` every other non-empty line of the block (the output
shown under a command) must also be a line of that command's standard output, spaces at the ends aside.
"""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from gap_validation.cli.main import COMMANDS, main

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = sorted((ROOT / "docs").glob("*.md"))
PAGES = [README, *DOCS]

_FENCE = re.compile(r"^(```|~~~)")
_LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
_CODE_SPAN = re.compile(r"`[^`]*`")
_MARK = re.compile(r"^<!--\s*runnable(:\s*output)?\s*-->\s*$")


def _prose_lines(text: str):
    """(line number, line) outside fenced code blocks, inline code spans removed."""
    fenced = False
    for number, line in enumerate(text.split("\n"), 1):
        if _FENCE.match(line.strip()):
            fenced = not fenced
            continue
        if not fenced:
            yield number, _CODE_SPAN.sub("", line)


def _slug(heading: str) -> str:
    """GitHub's anchor of a heading: the rendered text lowercased, punctuation but - and _ dropped, spaces ->
    -."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading).replace("`", "").replace("*", "")
    text = re.sub(r"[^\w\- ]", "", text.strip().lower())
    return text.replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    """Every heading anchor of a markdown file (repeated headings get -1, -2, ... as on GitHub)."""
    seen: dict[str, int] = {}
    anchors = set()
    fenced = False
    for line in path.read_text().split("\n"):
        if _FENCE.match(line.strip()):
            fenced = not fenced
            continue
        match = re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", line)
        if fenced or not match:
            continue
        slug = _slug(match.group(1))
        count = seen.get(slug, 0)
        seen[slug] = count + 1
        anchors.add(slug if count == 0 else f"{slug}-{count}")
    return anchors


def _links(path: Path):
    """(line number, target) of every link and image in the prose of a markdown file."""
    for number, line in _prose_lines(path.read_text()):
        for match in _LINK.finditer(line):
            yield number, match.group(1)


def _relative(target: str) -> bool:
    return not re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I)


def test_every_docs_page_is_linked_from_the_readme():
    linked = {(README.parent / target.split("#")[0]).resolve() for _, target in _links(README)
              if _relative(target) and not target.startswith("#")}
    missing = [p.name for p in DOCS if p.resolve() not in linked]
    assert not missing, f"docs pages the README does not link: {missing}"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_relative_link_and_anchor_resolves(page):
    broken = []
    for number, target in _links(page):
        if not _relative(target):
            continue
        file_part, _, anchor = target.partition("#")
        dest = (page.parent / file_part).resolve() if file_part else page
        where = f"{page.relative_to(ROOT)}:{number}: {target}"
        if not dest.exists():
            broken.append(f"{where}: no such file")
        elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest):
            broken.append(f"{where}: no heading with anchor #{anchor} in {dest.relative_to(ROOT)}")
    assert not broken, "\n".join(broken)


def _runnable_blocks():
    """(id, commands with the output lines shown under each, whether that output is checked) of every marked
    block of the README and docs."""
    blocks = []
    for page in PAGES:
        lines = page.read_text().split("\n")
        for i, line in enumerate(lines):
            mark = _MARK.match(line.strip())
            if not mark:
                continue
            fence = lines[i + 1].strip() if i + 1 < len(lines) else ""
            assert fence == "```console", (
                f"{page.relative_to(ROOT)}:{i + 1}: a runnable mark must precede a ```console block, got "
                f"{fence!r}"
            )
            commands: list[tuple[str, list[str]]] = []
            for body in lines[i + 2:]:
                if body.strip() == "```":
                    break
                if body.startswith("$ "):
                    commands.append((body[2:].strip(), []))
                elif body.strip() and commands:
                    commands[-1][1].append(body.strip())
            assert commands, f"{page.relative_to(ROOT)}:{i + 1}: a runnable block without a '$ ' command"
            blocks.append((f"{page.relative_to(ROOT).as_posix()}:{i + 1}", commands, bool(mark.group(1))))
    return blocks


BLOCKS = _runnable_blocks()


def test_the_readme_and_the_docs_have_runnable_blocks():
    """The marks are found (a typo in the marker would silently run nothing)."""
    pages = {block_id.split(":")[0] for block_id, _, _ in BLOCKS}
    assert "README.md" in pages and "docs/cli.md" in pages, pages


@pytest.mark.parametrize("block_id, commands, check_output", BLOCKS, ids=[b[0] for b in BLOCKS])
def test_runnable_commands_of_the_docs_run(block_id, commands, check_output, tmp_path):
    for name in ("config", "bags"):
        (tmp_path / name).symlink_to(ROOT / name, target_is_directory=True)
    env = dict(os.environ)
    env["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), env.get("PATH", "")])
    env["PYTHONPATH"] = os.pathsep.join(p for p in [str(ROOT), env.get("PYTHONPATH", "")] if p)
    for command, shown in commands:
        proc = subprocess.run(["bash", "-c", command], cwd=tmp_path, env=env, capture_output=True, text=True,
                              timeout=300)
        assert proc.returncode == 0, (f"{block_id}: `{command}` exited {proc.returncode}\n"
                                      f"stdout:\n{proc.stdout[-3000:]}\nstderr:\n{proc.stderr[-3000:]}")
        if check_output:
            printed = {line.strip() for line in proc.stdout.split("\n")}
            missing = [line for line in shown if line not in printed]
            assert not missing, f"{block_id}: `{command}` did not print {missing}; it printed:\n{proc.stdout}"


@pytest.mark.parametrize("command", [None, *(name.replace("_", "-") for name in COMMANDS)])
def test_no_help_text_shows_restructuredtext_double_backticks(command, capsys):
    """What argparse prints for ``--help`` is plain text: the module docstrings it shows carry no RST
    markup."""
    with pytest.raises(SystemExit) as stop:
        main([command, "--help"] if command else ["--help"])
    assert stop.value.code == 0
    shown = capsys.readouterr().out
    assert "usage: gap-validate" in shown
    assert "``" not in shown, [line for line in shown.split("\n") if "``" in line]
