"""mkdocs hook: the command-line reference, generated from rigcal's typer app at build time.

A page that contains the line ``<!-- rigcal-cli -->`` gets, in its place, every command of
``rigcal.cli.app`` in the app's own order: its help text, its usage line, and its arguments
and options as tables (one per typer help panel), each with the help text, default and
environment variable the command's own ``--help`` prints. The page therefore cannot drift
from the code. Only ``rigcal.cli`` is imported, so the hook does not depend on where the
commands' implementations live.
"""

from __future__ import annotations

import sys
from pathlib import Path

MARKER = "<!-- rigcal-cli -->"


def on_config(config, **kwargs):
    """Let a checkout build its docs without installing rigcal: app/ goes first on sys.path."""
    app_dir = Path(config["config_file_path"]).resolve().parent / "app"
    if app_dir.is_dir() and str(app_dir) not in sys.path:
        sys.path.insert(0, str(app_dir))
    return config


def on_page_markdown(markdown, page, config, files, **kwargs):
    if MARKER not in markdown:
        return markdown
    return markdown.replace(MARKER, cli_markdown())


def cli_markdown(app=None) -> str:
    """Every command of `app` (default: rigcal's) as Markdown."""
    import click
    import typer.main

    if app is None:
        from rigcal.cli import app

    group = typer.main.get_command(app)
    ctx = click.Context(group, info_name="rigcal")
    out = [_paragraphs(group.help or ""), "", _usage(group, ctx), ""]
    out += _params_tables(group, ctx, heading="####")
    for name in group.list_commands(ctx):
        command = group.get_command(ctx, name)
        if command is None or command.hidden:
            continue
        sub = click.Context(command, info_name=name, parent=ctx)
        out += [f"## rigcal {name}", "", _paragraphs(command.help or ""), "", _usage(command, sub), ""]
        out += _params_tables(command, sub, heading="###")
    return "\n".join(out) + "\n"


def _usage(command, ctx) -> str:
    """The usage line, arguments by their upper-case names as --help prints them."""
    pieces = ["[OPTIONS]"]
    for param in command.get_params(ctx):
        if param.param_type_name != "argument":
            continue
        name = param.name.upper() + ("..." if param.nargs == -1 else "")
        pieces.append(name if param.required else f"[{name}]")
    if hasattr(command, "list_commands"):
        pieces.append("COMMAND [ARGS]...")
    return f"```text\n{ctx.command_path} {' '.join(pieces)}\n```"


def _params_tables(command, ctx, heading: str) -> list[str]:
    """The command's arguments, its options without a panel, then each typer rich_help_panel
    in the order its first option appears (as --help shows them)."""
    panels: dict[str, list[tuple[str, str]]] = {}
    for param in command.get_params(ctx):
        if getattr(param, "hidden", False) or param.name == "help":
            continue
        record = param.get_help_record(ctx)
        if record is None:
            continue
        default_panel = "Arguments" if param.param_type_name == "argument" else "Options"
        panel = getattr(param, "rich_help_panel", None) or default_panel
        panels.setdefault(panel, []).append(record)
    order = sorted(panels, key=lambda p: (p != "Arguments", p != "Options"))
    lines: list[str] = []
    for panel in order:
        lines += [f"{heading} {panel}", "", "| | |", "|---|---|"]
        lines += [f"| `{_cell(name, code=True)}` | {_cell(text)} |" for name, text in panels[panel]]
        lines.append("")
    return lines


def _paragraphs(text: str) -> str:
    """Help text as Markdown: click's \\b (no-rewrap) markers dropped, blank lines kept."""
    return "\n".join(line for line in text.replace("\b", "").splitlines()).strip()


def _cell(text: str, code: bool = False) -> str:
    """One table cell: a code span (whose pipes the table leaves alone) or escaped text."""
    text = " ".join(text.split())
    if code:
        return text.replace("`", "'")
    return text.replace("|", "\\|").replace("<", "&lt;").replace("*", "\\*").replace("_", "\\_")
