"""``mcverify report``: regenerate a run folder's summary, tables, figures and report."""

from __future__ import annotations

import argparse
from pathlib import Path

from mcverify.cli import options


def add(sub, parents: list[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("report", parents=parents,
                       help="regenerate summary.json, cells.parquet, tables, figures, report.md and report.html")
    p.add_argument("run_dir", type=Path)
    p.add_argument("--level", type=options.level, default=None,
                   help="confidence level of every interval (default 0.95; an estimate folder keeps its own)")
    p.add_argument("--method", choices=("clopper-pearson", "wilson"), default=None,
                   help="two-sided interval for the rates of a fixed-count run (default: exact Clopper-Pearson); "
                        "an estimate folder's rates carry its estimator's anytime-valid interval")
    p.add_argument("--bootstrap-resamples", type=options.positive_int, default=2000,
                   help="resamples of the (seeded) bootstrap interval of every mean (default 2000)")
    p.add_argument("--format", action="append", choices=("png", "svg", "pdf"), dest="formats", default=[],
                   help="also write every figure in this format beside the report's PNG (repeatable)")
    p.add_argument("--dpi", type=options.positive_int, default=None,
                   help="resolution of the --format files (default 300; the report's own PNGs stay at 100)")
    p.add_argument("--audit", action="store_true",
                   help="first re-simulate every unsafe episode not audited yet with the reference solver "
                        "(mcverify replay --backend ipopt; about a minute of CPU each) and say in the report "
                        "which are confirmed by it and which are solver-dependent")
    p.set_defaults(handler="report")


def command(args) -> int:
    from mcverify.errors import RunError
    from mcverify.reporting import run_report

    if args.dpi is not None and not args.formats:
        raise RunError("--dpi sets the resolution of the --format files: add --format png, svg or pdf")
    kind = _own_report_kind(args.run_dir)
    if kind is not None:
        return _rebuild_own_report(args, kind)
    if args.audit:
        import sys

        from mcverify.campaign.audit import audit_unsafe

        audit_unsafe(args.run_dir, progress=lambda msg: print(msg, file=sys.stderr))
    path = run_report.write(
        args.run_dir, level=args.level, method=args.method, bootstrap_resamples=args.bootstrap_resamples,
        figure_formats=args.formats, figure_dpi=args.dpi or 300,
    )
    print(f"report: {path} (also report.html, summary.json, cells.parquet, tables/, figures/)")
    return 0


def _own_report_kind(run_dir: Path) -> str | None:
    """``falsify`` for a search folder, ``splitting`` or ``importance`` for such an estimate folder:
    folders whose report their own code writes (None: a run or a crude Monte Carlo estimate)."""
    from mcverify.estimate.replay import estimate_method
    from mcverify.falsify import search

    if (Path(run_dir) / search.CONFIG).is_file():
        return "falsify"
    return estimate_method(Path(run_dir))


def _rebuild_own_report(args, kind: str) -> int:
    """Rewrite a complete search's or splitting / importance estimate's report from its stored
    results, running nothing (what ``--resume`` of such a folder did before the one ``--resume`` rule)."""
    from mcverify.errors import RunError

    given = [opt for opt, value in (("--level", args.level), ("--method", args.method),
                                    ("--audit", args.audit and kind != "falsify"), ("--format", args.formats))
             if value]
    if args.audit and kind != "falsify":
        raise RunError(f"--audit is for run, crude Monte Carlo estimate and search folders; {args.run_dir} is a "
                       f"{kind} estimate folder: `mcverify replay {args.run_dir} K --backend ipopt` audits its "
                       "counterexample K")
    if given:
        raise RunError(f"{given[0]} is for run and crude Monte Carlo estimate folders; {args.run_dir} is a "
                       f"{kind} folder")
    command = "falsify" if kind == "falsify" else "estimate"
    if not options.already_complete(args.run_dir):
        raise RunError(f"{args.run_dir} is not complete: `mcverify {command} --resume {args.run_dir}` finishes it "
                       "and writes its report")

    def run_nothing(*_args, **_kw):
        raise RunError(f"{args.run_dir}: its stored results do not cover the search; not rebuilt")

    if kind == "falsify":
        from mcverify.campaign import executors
        from mcverify.falsify import beam_folder, search

        if beam_folder.is_beam_folder(args.run_dir):
            if args.audit:
                raise RunError(f"--audit: a beam search's counterexample is the run folder {args.run_dir}/best; "
                               f"`mcverify report {args.run_dir}/best --audit` audits it")
            path = beam_folder.write_report(args.run_dir, beam_folder.read_summary(args.run_dir))
            print(f"report: {path}")
            return 0
        if args.audit:
            _audit_search(Path(args.run_dir))
        path = search.resume(args.run_dir, make_executor=executors.SerialExecutor, episode_fn=run_nothing).out_dir
        path = path / "report.md"
    else:
        from mcverify import store
        from mcverify.campaign import runner
        from mcverify.campaign.spec import campaign_from_dict
        from mcverify.estimate import importance_run, splitting_run, subset_run

        manifest = store.read_manifest(args.run_dir)
        camp = manifest["campaign"]
        campaign = runner.with_recorded_params(
            campaign_from_dict(camp["raw"], source=camp["source"], seed=camp["seed"]), manifest.get("cells", []),
            str(args.run_dir))
        module = {"splitting": splitting_run, "subset": subset_run, "importance": importance_run}[kind]
        path = module.resume(args.run_dir, campaign, progress=lambda msg: None)
    print(f"report: {path} (also report.html)")
    return 0


def _audit_search(out_dir: Path) -> None:
    """Audit every counterexample of a finished search not audited yet (kept in its generation folders)."""
    import sys

    import pyarrow.parquet as pq

    from mcverify import store
    from mcverify.analysis.robustness import needs_trajectory
    from mcverify.errors import RunError
    from mcverify.falsify import audit, search

    requirement = search.SearchConfig.from_json(store.read_json(out_dir / search.CONFIG)).requirement
    if needs_trajectory(requirement):
        raise RunError(f"--audit judges a named requirement; {out_dir} searched the STL requirement {requirement!r} "
                       "(`mcverify replay GEN_DIR E --backend ipopt` audits an episode's safety)")
    records = pq.read_table(out_dir / search.COUNTEREXAMPLES).to_pylist()
    audit.audit_all(out_dir, records, requirement, progress=lambda msg: print(msg, file=sys.stderr))
