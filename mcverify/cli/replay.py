"""``mcverify replay``: re-simulate one stored episode and write its trajectory."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mcverify.cli import options


def add(sub, parents: list[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("replay", parents=parents, help="re-simulate one stored episode and write its trajectory")
    p.add_argument("run_dir", type=Path,
                   help="run folder (a search's generation folder, e.g. SEARCH/generations/g000, is one), or "
                          "an importance-sampling, splitting or subset simulation estimate folder")
    p.add_argument("episode_id", type=options.nonneg_int,
                   help="the episode's id (column episode_id, from 0); in an importance-sampling estimate "
                          "folder a final draw's cell_episode, in a splitting one a failing particle's place in "
                          "the cell's failing_particles, in a subset simulation one a failing sample's place in "
                          "the cell's failing_samples")
    p.add_argument("--out", type=Path, help="folder for the trajectory and plot (default: RUN_DIR/replay)")
    p.add_argument("--cell", metavar="NAME",
                   help="estimate folders: the cell of the draw, particle or sample (needed when the folder "
                          "estimates several cells)")
    p.add_argument("--backend", choices=("ipopt",), default=None,
                   help="audit instead: re-simulate the episode on the same noise with the reference solver "
                        "(IPOPT at every step) and say whether its safety verdict is confirmed by the reference "
                        "solver or solver-dependent (run and estimate folders)")
    p.set_defaults(handler="replay")


def _performance_of(est_dir) -> str:
    """The performance function a subset simulation folder's runs climbed (its failing samples keep its value)."""
    from mcverify import store
    from mcverify.requirements import PERFORMANCES

    return store.read_manifest(est_dir)["estimate"].get("performance", PERFORMANCES[0])


def command(args) -> int:
    from mcverify import api
    from mcverify.campaign.replay import ReplayMismatch
    from mcverify.estimate.replay import estimate_method

    method = estimate_method(args.run_dir)
    if args.backend is not None:
        return _audit(args, method)
    try:
        res = api.replay(args.run_dir, args.episode_id, args.out, cell=args.cell)
    except ReplayMismatch as err:
        print(f"mcverify: replay FAILED: {err}", file=sys.stderr)
        return options.EXIT_MISMATCH
    if method == "splitting":
        print(f"failing particle {res.episode_id} reproduced exactly (its running score at its last step) "
              f"({res.row['outcome']}, safe={res.row['safe']})")
    elif method == "subset":
        print(f"failing sample {res.episode_id} reproduced exactly (its {_performance_of(args.run_dir)} value) "
              f"({res.row['outcome']}, safe={res.row['safe']})")
    else:
        kept = " (the values its estimate folder keeps)" if method else ""
        print(f"episode {res.episode_id} reproduced exactly{kept} ({res.row['outcome']}, safe={res.row['safe']})")
    if res.not_stored:
        print(f"(not compared: {len(res.not_stored)} column(s) newer than the run: {', '.join(res.not_stored)})")
    print(f"trajectory: {res.trajectory_path}")
    print(f"plot: {res.plot_path}")
    return 0


def _audit(args, method: str | None) -> int:
    from mcverify.campaign.audit import audit, record
    from mcverify.errors import RunError

    if method:
        from mcverify.estimate import audit as estimate_audit

        checked = estimate_audit.audit(args.run_dir, args.episode_id, args.out, args.cell)
        print(checked.describe())
        print(f"trajectories: {checked.stored.trajectory_path}, {checked.reference.trajectory_path}")
        print(f"plots: {checked.stored.plot_path}, {checked.reference.plot_path}")
        return 0
    if args.cell is not None:
        raise RunError("--cell names the cell of an estimate folder's draw, particle or sample; a run folder's "
                       "episode id needs none")
    res = audit(args.run_dir, args.episode_id, args.out)
    record(args.run_dir, res)
    print(res.describe())
    if res.trajectory_path is not None:
        print(f"trajectory: {res.trajectory_path}")
        print(f"plot: {res.plot_path}")
    return 0
