"""train.metrics_log: each step's line names the auxiliary losses a run adds, and the file keeps them."""

from kosmos_jax.train.metrics_log import MetricsLog, read_metrics


def _step(**extra):
    return {"step": 3, "loss": 1.5, "learning_rate": 1e-3, "grad_norm": 2.0, "examples_per_s": 10.0,
            "data_wait_fraction": 0.0, **extra}


def test_step_lines_name_the_auxiliary_losses_the_run_logs(tmp_path, capsys):
    log = MetricsLog(tmp_path, total_steps=10, start_step=0, interactive=False)
    log.write(_step())
    log.write(_step(pointing=1.0, tower_angle=0.25))
    lines = capsys.readouterr().err.splitlines()
    assert lines[0].startswith("step 3/10: loss 1.5000, lr") and "pointing" not in lines[0]
    assert "loss 1.5000, pointing 1.000, tower angle 0.250, lr" in lines[1]
    assert read_metrics(tmp_path)[1]["tower_angle"] == 0.25


def test_every_auxiliary_loss_the_train_step_can_add_is_one_the_log_names():
    import dataclasses

    from kosmos_jax.train.auxiliary import AuxiliaryLosses
    from kosmos_jax.train.metrics_log import AUXILIARY_LOSSES

    weights = {f.name.removesuffix("_loss") for f in dataclasses.fields(AuxiliaryLosses) if f.name.endswith("_loss")}
    assert weights == set(AUXILIARY_LOSSES)
