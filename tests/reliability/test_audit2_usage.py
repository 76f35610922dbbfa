"""Second hostile-input audit (issue #25): every command's usage error is one line and exit 2.

argparse prints its usage block above the error line; the main command and every subcommand
(``report``, ``compare``, ``enhance``) print only ``PROG: error: MESSAGE (see PROG --help)``,
like the input errors, so a CI log shows the one line that matters."""

from __future__ import annotations

import pytest

CASES = [
    (["--no-such-flag"], "unrecognized arguments: --no-such-flag"),
    (["t.txt", "--limit", "x"], "argument --limit: invalid int value: 'x'"),
    (["t.txt", "--matcher", "foo"], "argument --matcher: invalid choice: 'foo'"),
    (["t.txt", "--executor"], "argument --executor: expected one argument"),
    (["report"], "the following arguments are required: out_dir"),
    (["report", "OUT", "--shared-checks", "ture"], "argument --shared-checks"),
    (["report", "OUT", "--threshold-px", "x"], "argument --threshold-px: invalid float"),
    (["compare"], "the following arguments are required: a, b"),
    (["compare", "a", "b", "--tie-px", "x"], "argument --tie-px: invalid float value"),
    (["compare", "a", "b", "--bogus"], "unrecognized arguments: --bogus"),
    (["enhance"], "the following arguments are required"),
    (["enhance", "t.txt", "--limit", "x"], "argument --limit: invalid int value: 'x'"),
]


@pytest.mark.parametrize(("argv", "message"), CASES)
def test_usage_error_is_one_line_exit_2(argv, message, capsys, case):
    from pgt_check.cli import main

    rc = main(argv)
    out, err = capsys.readouterr()
    prog = "pgt-check" + (f" {argv[0]}" if argv[0] in ("report", "compare", "enhance") else "")
    case(f"pgt-check {' '.join(argv)}", "2, one line (no usage block)",
         f"{rc}: {err.strip()[:110]}")
    assert rc == 2 and out == ""
    assert len(err.splitlines()) == 1, err
    assert err.startswith(f"{prog}: error: ") and message in err
    assert err.rstrip().endswith(f"(see {prog} --help)") and "usage:" not in err


@pytest.mark.parametrize("sub", [[], ["report"], ["compare"], ["enhance"]])
def test_help_still_shows_usage(sub, capsys):
    from pgt_check.cli import main

    assert main([*sub, "--help"]) == 0
    assert capsys.readouterr().out.startswith("usage: pgt-check")


def test_missing_mesh_is_one_line(capsys):
    from pgt_check.cli import main

    assert main(["t.txt"]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and err.startswith("pgt-check: error: ")
