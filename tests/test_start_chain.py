"""An exported folder names the starts behind its run (workdir.pretrained.start_chain): through an
exported folder's kosmos_e.json and a workdir's run.json, nearest first, as far as the records reach."""

import json

from kosmos_jax.workdir.pretrained import FORMAT_FILE, start_chain


def write_run(workdir, init=None):
    workdir.mkdir(parents=True)
    (workdir / "run.json").write_text(json.dumps({"config": {}, **({"init": init} if init else {})}))
    return workdir


def write_export(folder, workdir, step, started_from):
    folder.mkdir(parents=True)
    (folder / FORMAT_FILE).write_text(json.dumps(
        {"format": {}, "tokenizer": {}, "protocol": "honest", "grasp_size": [1.0, 1.0], "step": step,
         "workdir": str(workdir), "started_from": started_from}))
    return folder


def test_a_run_from_scratch_has_no_chain():
    assert start_chain(None) == [] and start_chain({}) == []


def test_the_chain_runs_through_workdirs_and_exported_folders(tmp_path):
    first = write_run(tmp_path / "first")  # from scratch
    older = [{"workdir": str(first), "step": 6000}]
    folder = write_export(tmp_path / "start6000", tmp_path / "cont", 4000, older)
    middle = write_run(tmp_path / "middle", {"from": str(folder), "step": 4000, "exported": True})
    chain = start_chain({"from": str(middle), "step": 300})
    assert chain == [{"workdir": str(middle), "step": 300},
                     {"folder": str(folder), "step": 4000, "workdir": str(tmp_path / "cont")},
                     {"workdir": str(first), "step": 6000}]


def test_a_start_gone_from_the_machine_ends_the_chain_with_its_record(tmp_path):
    gone_folder = {"from": str(tmp_path / "gone"), "step": 10, "exported": True}
    assert start_chain(gone_folder) == [{"folder": str(tmp_path / "gone"), "step": 10}]
    assert start_chain({"from": str(tmp_path / "no_run"), "step": 5}) == [{"workdir": str(tmp_path / "no_run"), "step": 5}]


def test_a_folder_exported_before_chains_were_written_ends_the_chain(tmp_path):
    folder = write_export(tmp_path / "old", tmp_path / "its_run", 6000, [])
    described = json.loads((folder / FORMAT_FILE).read_text())
    del described["started_from"]
    (folder / FORMAT_FILE).write_text(json.dumps(described))
    assert start_chain({"from": str(folder), "step": 6000, "exported": True}) == [
        {"folder": str(folder), "step": 6000, "workdir": str(tmp_path / "its_run")}]
