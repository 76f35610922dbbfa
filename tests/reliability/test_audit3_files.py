"""Third audit (#39), files that are not ours: a run replaces or removes only the output files
an earlier run of the tool wrote there (the completion marker lists them; while a run's outputs
are incomplete, its run.json claims them); any other file of an output name stops the run with
exit 2 naming it. Every output, the record store included, replaces a symlink instead of
writing through it."""

from __future__ import annotations

import json

import pytest

USER = "the user's own file\n"
SESSION = ("calibrated/trajectories.txt", "calibrated/sensors.txt", "calibrated/images.txt",
           "calibrated/rigs.txt")


def _user_files(out, names):
    for name in names:
        (out / name).parent.mkdir(parents=True, exist_ok=True)
        (out / name).write_text(USER)


def _error_line(err: str) -> str:
    assert "Traceback" not in err
    return err.strip().splitlines()[-1] if err.strip() else ""


@pytest.mark.parametrize("names", [SESSION, ("registered_trajectory.txt",),
                                   ("calibrated_sensors.txt",), ("frames.csv",)])
def test_files_of_an_output_name_in_a_new_out_are_kept(names, tmp_path, cli, base_args, case):
    out = tmp_path / "out"
    _user_files(out, names)
    rc, _, err = cli(*base_args(out=out))
    line = _error_line(err)
    case(f"user's {names[0]} in a new --out", "2, names the file, kept",
         f"{rc}: {line[:150]}")
    assert rc == 2 and "not written by pgt-check" in line
    assert any(n in line for n in names)
    assert all((out / n).read_text() == USER for n in names)
    assert not (out / "records.jsonl").exists()  # refused before anything was written


def test_files_added_after_a_run_are_kept_by_the_next_run(tmp_path, cli, base_args, case):
    """The issue's case: a clean run (no calibration finding) deleted a calibrated/ session
    of the user's, registered_trajectory.txt and calibrated_sensors.txt unconditionally."""
    out = tmp_path / "out"
    assert cli(*base_args(out=out))[0] == 0
    names = (*SESSION, "registered_trajectory.txt", "calibrated_sensors.txt")
    _user_files(out, names)
    rc, _, err = cli(*base_args(out=out))
    line = _error_line(err)
    rc_report, _, err_report = cli("report", out)
    case("user's calibrated/ session added to a finished --out, run again / report",
         "2 naming the file, all kept", f"{rc}: {line[:120]}; report {rc_report}")
    assert rc == 2 and "not written by pgt-check" in line
    assert rc_report == 2 and "calibrated_sensors.txt" in _error_line(err_report)
    assert all((out / n).read_text() == USER for n in names)


def test_files_an_earlier_run_wrote_are_replaced_or_removed(tmp_path, cli, base_args):
    """What the marker lists is the tool's: a stale calibrated/ of an earlier run (listed) goes
    when this run has no calibration finding, the folder with it when empty."""
    from pgt_check.report.outputs import COMPLETION_MARKER, outputs_complete

    out = tmp_path / "out"
    assert cli(*base_args(out=out))[0] == 0
    _user_files(out, (*SESSION, "calibrated_sensors.txt"))
    marker = json.loads((out / COMPLETION_MARKER).read_text())
    marker["files"].update({n: "0" * 64 for n in (*SESSION, "calibrated_sensors.txt")})
    (out / COMPLETION_MARKER).write_text(json.dumps(marker))  # as if a run had written them
    assert cli(*base_args(out=out))[0] == 0
    assert not (out / "calibrated").exists() and not (out / "calibrated_sensors.txt").exists()
    assert outputs_complete(out) == (True, "")
    listed = json.loads((out / COMPLETION_MARKER).read_text())["files"]
    assert "frames.csv" in listed and "assets/plot_error_hist.svg" in listed


def test_a_run_stopped_before_its_outputs_resumes(tmp_path, cli, base_args):
    """No marker (a run killed while it wrote its outputs): run.json claims the output names
    it found free or the tool's, so --resume and report rebuild them."""
    from pgt_check.report.outputs import COMPLETION_MARKER

    out = tmp_path / "out"
    assert cli(*base_args(out=out))[0] == 0
    (out / COMPLETION_MARKER).unlink()
    assert "frames.csv" in json.loads((out / "run.json").read_text())["outputs"]
    assert cli("report", out)[0] == 0
    (out / COMPLETION_MARKER).unlink()
    assert cli(*base_args("--resume", out=out))[0] == 0
    assert (out / COMPLETION_MARKER).is_file()


def test_records_jsonl_symlink_is_replaced_not_written_through(tmp_path, cli, base_args, case):
    out = tmp_path / "out"
    out.mkdir()
    user = tmp_path / "user.txt"
    user.write_text(USER)
    (out / "records.jsonl").symlink_to(user)
    rc, _, err = cli(*base_args(out=out))
    case("OUT/records.jsonl a symlink to a user's file", "replaced, the file unchanged",
         f"{rc}: user file {'unchanged' if user.read_text() == USER else 'WRITTEN'}, "
         f"records.jsonl {'a link' if (out / 'records.jsonl').is_symlink() else 'a file'}")
    assert rc == 0 and user.read_text() == USER
    assert not (out / "records.jsonl").is_symlink()
    assert len((out / "records.jsonl").read_text().splitlines()) == 2


def test_every_output_symlink_is_replaced_not_written_through(tmp_path, cli, base_args):
    """After a finished run, each output the tool wrote made a link to a file of the user's:
    the next run replaces each link with its own file and leaves the linked files alone."""
    from pgt_check.report.outputs import COMPLETION_MARKER

    out = tmp_path / "out"
    assert cli(*base_args(out=out))[0] == 0
    listed = json.loads((out / COMPLETION_MARKER).read_text())["files"]
    names = [*listed, "records.jsonl", "run.json"]
    for i, name in enumerate(names):
        target = tmp_path / f"user{i}.txt"
        target.write_text(USER)
        (out / name).unlink()
        (out / name).symlink_to(target)
    assert cli(*base_args(out=out))[0] == 0
    assert all((tmp_path / f"user{i}.txt").read_text() == USER for i in range(len(names)))
    assert not any((out / n).is_symlink() for n in names)
