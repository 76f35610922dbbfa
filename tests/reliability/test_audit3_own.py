"""Third audit (#39), the closing hostile audit: what it found that lost a user's file or passed
a gate it should not have. The store's own files (run.json, records.jsonl, the completion
marker) of another tool in ``--out`` were replaced (``--overwrite``: records.jsonl emptied)."""

from __future__ import annotations

import pytest

USER = "the user's own file\n"


def _error_line(err: str) -> str:
    assert "Traceback" not in err
    return err.strip().splitlines()[-1] if err.strip() else ""


@pytest.mark.parametrize("overwrite", [False, True])
@pytest.mark.parametrize("name", ["run.json", "records.jsonl", "outputs.complete.json"])
def test_store_files_of_another_tool_are_kept(name, overwrite, tmp_path, cli, base_args, case):
    out = tmp_path / "out"
    out.mkdir()
    (out / name).write_text(USER)
    extra = ("--overwrite",) if overwrite else ()
    rc, _, err = cli(*base_args(*extra, out=out))
    line = _error_line(err)
    case(f"a {name} of the user's in a new --out{' (--overwrite)' if overwrite else ''}",
         "2, names the file, kept", f"{rc}: {line[-130:]}")
    assert rc == 2 and "not written by pgt-check" in line and name in line
    assert (out / name).read_text() == USER
    assert sorted(p.name for p in out.iterdir()) == [name]


def test_api_overwrite_keeps_a_run_json_of_another_tool(scene, tmp_path):
    from pgt_check.api import check
    from pgt_check.errors import InputError

    out = tmp_path / "out"
    out.mkdir()
    (out / "run.json").write_text('{"epochs": 3}\n')
    with pytest.raises(InputError, match="not written by pgt-check"):
        check(scene / "trajectories.txt", scene / "mesh.glb", out=out, limit=1, overwrite=True)
    assert (out / "run.json").read_text() == '{"epochs": 3}\n'


def test_the_tools_own_store_files_are_still_reused(tmp_path, cli, base_args):
    """A finished run's folder (and one whose run.json was damaged: settings unknown) is the
    tool's: rerun, --resume and --overwrite work as before."""
    out = tmp_path / "out"
    assert cli(*base_args(out=out))[0] == 0
    assert cli(*base_args(out=out))[0] == 0
    (out / "run.json").write_text("[1, 2]\n")
    assert cli(*base_args("--overwrite", out=out))[0] == 0


def test_report_refuses_its_own_summary_as_the_trusted_calibration(tmp_path, cli, base_args,
                                                                   case):
    """``pgt-check report OUT --calibration-from OUT/summary.json`` took the run's own
    estimate as the trusted calibration, passed the gate, and rewrote the file it names (a
    run refuses the same: --out would overwrite its input)."""
    out = tmp_path / "out"
    assert cli(*base_args("--remove-calibration", "--limit", "3", out=out))[0] in (0, 1)
    before = (out / "summary.json").read_bytes()
    rc, _, err = cli("report", out, "--calibration-from", out / "summary.json")
    line = _error_line(err)
    case("report OUT --calibration-from OUT/summary.json", "2, the file kept",
         f"{rc}: {line[-120:]}")
    assert rc == 2 and "--calibration-from" in line and "trusted" in line
    assert (out / "summary.json").read_bytes() == before
    trusted = tmp_path / "trusted.json"
    trusted.write_bytes(before)
    assert cli("report", out, "--calibration-from", trusted)[0] in (0, 1)
