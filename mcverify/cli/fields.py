"""``mcverify fields``: every model field a campaign can set."""

from __future__ import annotations

import argparse


def add(sub, parents: list[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("fields", parents=parents,
                       help="every model field a campaign can set: type, unit, default, meaning")
    p.add_argument("pattern", nargs="?", default="", help="only fields whose name contains this text")
    p.set_defaults(handler="fields")


def command(args) -> int:
    from mcverify import fields

    table = fields.markdown_table().splitlines()
    rows = [row for row in table[2:] if args.pattern in row.split("|")[1]]
    if not rows:
        from mcverify.errors import CampaignError

        raise CampaignError(f"no model field contains {args.pattern!r} (`mcverify fields` lists them all)")
    print("\n".join(table[:2] + rows))
    return 0
