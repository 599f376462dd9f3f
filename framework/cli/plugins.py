"""``surgiplan plugins``: installed stage kinds and plugins, where each came from, and what failed to load."""

from __future__ import annotations

import json
import sys


def add_parsers(sub) -> None:
    plugins = sub.add_parser("plugins", help="list installed plugins and stage kinds")
    plugins.add_argument("--json", action="store_true", help="machine-readable output")
    plugins.set_defaults(handler=_cmd_plugins)


def _cmd_plugins(args) -> int:
    from ..registry import default_registry

    registry = default_registry()
    rows = [
        {
            "name": p.name,
            "kind": p.kind,
            "package": p.package,
            "version": p.version,
            "description": p.description,
            "available": not p.unavailable,
            "unavailable": p.unavailable,
        }
        for p in registry.all()
    ]
    rows += [
        {
            "name": info.name,
            "kind": "stage kind",
            "package": info.package,
            "version": info.version,
            "description": info.kind.description,
            "available": True,
            "unavailable": "",
        }
        for info in sorted(registry.stage_kinds.values(), key=lambda i: i.name)
    ]
    if args.json:
        print(json.dumps({"plugins": rows, "failures": [f.__dict__ for f in registry.failures]}, indent=2))
        return 0
    from rich.console import Console
    from rich.table import Table

    table = Table(title="surgiplan plugins", title_justify="left")
    for column in ("name", "kind", "package", "version"):
        table.add_column(column, no_wrap=True)
    table.add_column("description")
    for row in rows:
        description = row["description"] if row["available"] else f"[yellow]unavailable: {row['unavailable']}[/yellow]"
        table.add_row(row["name"], row["kind"], row["package"], row["version"], description)
    # a pipe or a CI log is not a terminal: do not squeeze the table into 80 columns
    console = Console() if sys.stdout.isatty() else Console(width=160)
    console.print(table)
    for failure in registry.failures:
        console.print(f"[red]failed:[/red] {failure.error}")
    return 0
