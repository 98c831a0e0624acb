"""Every shell command of the documentation that runs ``minari`` parses with the installed
Minari CLI (its Typer app, every command's body replaced by a no-op: nothing is
downloaded). Minari 0.5.4's ``minari download`` takes one data set id: a line with several
ids stops at once with "Got unexpected extra argument(s)"."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

typer_main = pytest.importorskip("typer.main")
minari_cli = pytest.importorskip("minari.cli")

ROOT = Path(__file__).resolve().parents[1]
PAGES = sorted([*ROOT.glob("docs/*.md"), ROOT / "README.md", ROOT / "benchmarks" / "README.md"])
_FENCE = re.compile(r"^```(?:bash|sh|shell|console)[ \t]*\n(.*?)^```", re.MULTILINE | re.DOTALL)
_INLINE = re.compile(r"`(minari [^`]+)`")
_SEPARATORS = re.compile(r"&&|\|\||;|\|")


def minari_commands(text: str) -> list[str]:
    """The ``minari ...`` commands of a page: in its shell blocks (continuation lines
    joined, comments dropped, split at ``&&``, ``||``, ``;``, ``|``) and its inline code
    spans that start with ``minari `` (placeholders such as ``<id>`` excepted)."""
    commands = []
    for block in _FENCE.findall(text):
        for line in block.replace("\\\n", " ").splitlines():
            if "minari" in line:
                code = " ".join(shlex.split(line, comments=True))
                commands += [part.strip() for part in _SEPARATORS.split(code)]
    # inline: a command with its arguments (`minari download` alone names the command)
    commands += [s for s in _INLINE.findall(text) if "<" not in s and len(s.split()) > 2]
    return [c for c in commands if c.split(" ", 1)[0] == "minari"]


def parse(command: str) -> None:
    """Parses ``command`` with Minari's CLI, running nothing; raises its usage error."""
    group = typer_main.get_command(minari_cli.app)
    for sub in group.commands.values():
        sub.callback = lambda *args, **kwargs: None
    group.main(shlex.split(command)[1:], prog_name="minari", standalone_mode=False)


def test_the_extraction_finds_block_and_inline_commands():
    page = (
        "```bash\npip install x  # minari download a\nminari download a \\\n    b   # two\n"
        "minari download c && python run.py\necho 'unclosed\n```\n`minari show d`, "
        "`minari download <id>`, `minari download`\n"
    )
    assert minari_commands(page) == ["minari download a b", "minari download c", "minari show d"]


def test_a_line_with_two_ids_is_refused_as_the_cli_refuses_it():
    parse("minari download D4RL/antmaze/umaze-v1")
    with pytest.raises(Exception, match="unexpected extra argument"):
        parse("minari download D4RL/antmaze/umaze-v1 D4RL/antmaze/umaze-diverse-v1")


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_minari_command_of_the_docs_parses(page):
    for command in minari_commands(page.read_text(encoding="utf-8")):
        try:
            parse(command)
        except Exception as err:  # the CLI's UsageError (Typer's own click)
            pytest.fail(f"{page.name}: `{command}` does not parse: {err}")


def test_the_reproducing_page_downloads_every_data_set_the_tables_read():
    from benchmarks.learning.paper_tables import runnable_rows

    commands = minari_commands((ROOT / "docs" / "reproducing.md").read_text(encoding="utf-8"))
    downloaded = {c.split()[-1] for c in commands if c.startswith("minari download ")}
    assert {row.data for row in runnable_rows()} <= downloaded
