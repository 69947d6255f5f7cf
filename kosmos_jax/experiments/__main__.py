"""`python -m kosmos_jax.experiments --config=configs/experiments/table1.py:cpu --workdir=runs/table1`

    [--config.folds=0,1] [--config.run_arms=kosmos_e] [--config.init_from=KOSMOS2_FOLDER]
    [--aggregate_only] [--check_only] [--records_from=DIR] [--records_to=DIR]

Trains and scores every (arm, protocol, scheme, fold) of the experiment not yet recorded under
WORKDIR (a killed sweep resumes: finished folds are skipped, a half-trained run resumes from its
checkpoint), then writes WORKDIR/results.json and table.md (and data_size.png/json for Fig. 6).
--aggregate_only only writes those from the folds recorded so far (after a SLURM array's tasks);
--check_only builds every arm's config and model shapes and trains nothing. --records_from=DIR first
copies the fold records kept in DIR (results/<experiment>/folds) into WORKDIR, so their folds are
skipped and aggregated; --records_to=DIR copies WORKDIR's records there at the end (carried.py), also when
the sweep is stopped (the folds finished before the stop are kept).
Exit status: 0 done,
1 a fold failed or the config is wrong, 3 stopped by SIGTERM (the same command resumes).
"""

from __future__ import annotations

import json
import shlex
import sys

from absl import flags, logging

from kosmos_jax import commands

PROG = "python -m kosmos_jax.experiments"


def define_flags(flag_values: flags.FlagValues) -> None:
    commands.define_config(flag_values, "config", None, "an experiment config, e.g. configs/experiments/table1.py:cpu")
    flags.DEFINE_string("workdir", None, "the experiment's folder: one run folder per arm and fold, results.json",
                        flag_values=flag_values)
    flags.DEFINE_bool("aggregate_only", False, "only aggregate the folds recorded so far", flag_values=flag_values)
    flags.DEFINE_bool("check_only", False, "build every arm's config and model shapes; train nothing",
                      flag_values=flag_values)
    flags.DEFINE_string("records_from", None, "a folder of fold records (as --records_to writes) to copy into "
                        "the workdir first: those folds are skipped and aggregated", flag_values=flag_values)
    flags.DEFINE_string("records_to", None, "a folder to copy the workdir's fold records into at the end",
                        flag_values=flag_values)
    flags.mark_flags_as_required(["config", "workdir"], flag_values=flag_values)


def command_line(arguments: list[str]) -> str:
    return " ".join([PROG, *(shlex.quote(a) for a in arguments)])


def main(argv=None) -> int:
    arguments = list(sys.argv[1:] if argv is None else argv)
    return commands.run_command(define_flags, lambda options: experiments_command(options, command_line(arguments)),
                                arguments, prog=PROG, doc=__doc__)


def experiments_command(options, command: str) -> int:
    logging.set_verbosity(logging.WARNING)
    from kosmos_jax.experiments import carried
    from kosmos_jax.experiments.aggregate import write_results
    from kosmos_jax.experiments.checks import check_experiment
    from kosmos_jax.experiments.runner import SweepStopped, run_experiment, sigterm_stops_the_sweep
    from kosmos_jax.experiments.spec import ExperimentError

    config = options.config
    try:
        if options.check_only:
            for report in check_experiment(config):
                print(json.dumps(report))
            return 0
        if options.records_from:
            brought = carried.bring_in(config, options.records_from, options.workdir)
            print(f"{len(brought)} fold records copied from {options.records_from} into {options.workdir}")
        summary, stopped = None, None
        if options.aggregate_only:
            results = write_results(config, options.workdir, command)
            print(f"aggregated {sum(len(r['folds']) for r in results['rows'] if r['kind'] == 'trained')} folds into "
                  f"{options.workdir}/results.json and table.md ({len(results['missing'])} not run yet)")
        else:
            try:
                with sigterm_stops_the_sweep():
                    summary = run_experiment(config, options.workdir, command=command)
            except SweepStopped as error:  # the folds finished before the stop are still carried out
                stopped = error
        if options.records_to:
            sent = carried.send_out(config, options.workdir, options.records_to)
            print(f"{len(sent)} fold records copied from {options.workdir} into {options.records_to}")
    except ExperimentError as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    if stopped is not None:
        print(f"stopped: {stopped}", file=sys.stderr)
        return 3
    if summary is None:
        return 0
    print(f"{summary['trained']} folds trained, {summary['skipped']} skipped, {len(summary['failed'])} failed")
    for name, error in summary["failed"]:
        print(f"failed: {name}: {error}", file=sys.stderr)
    return 1 if summary["failed"] else 0


if __name__ == "__main__":
    sys.exit(main())
