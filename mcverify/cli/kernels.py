"""``mcverify kernels list|clear``: the compiled-solver cache."""

from __future__ import annotations

import argparse


def add(sub, parents: list[argparse.ArgumentParser]) -> None:
    ker = sub.add_parser("kernels", parents=parents, help="the compiled-solver cache")
    ker.set_defaults(help_parser=ker)  # `mcverify kernels` alone prints this help, not the top-level one
    ksub = ker.add_subparsers(metavar="ACTION")
    ksub.add_parser("list", help="list cached kernels", parents=parents).set_defaults(handler="kernels_list")
    ksub.add_parser("clear", help="delete cached kernels", parents=parents).set_defaults(handler="kernels_clear")


def list_command(args) -> int:
    from mcverify.solver import kernels

    rows = kernels.list_kernels()
    if not rows:
        print("no cached kernels")
    for r in rows:
        print("  ".join(f"{k}={v}" for k, v in r.items()))
    return 0


def clear_command(args) -> int:
    from mcverify.solver import kernels

    print(f"removed {kernels.clear_kernels()} kernel(s)")
    return 0
