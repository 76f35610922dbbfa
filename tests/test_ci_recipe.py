"""docs/ci-github-actions.yml stays valid: a workflow with the documented steps, and every
``pgt-check`` / ``python -m pgt_check`` command in it uses flags that exist (checked against
the real ``--help`` output) with values the parser accepts."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
RECIPE = REPO / "docs" / "ci-github-actions.yml"
EGL_PACKAGES = {"libegl1", "libegl-mesa0", "libgl1", "libgl1-mesa-dri", "libgles2"}


def _minimal_steps(text: str) -> list[dict[str, str]]:
    """Without PyYAML: the steps' ``uses`` / ``run`` / ``name`` / ``if`` values (block scalars
    ``run: |`` included), enough for the checks below."""
    steps: list[dict[str, str]] = []
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        m = re.match(r"^(\s*)- (name|uses|run|if):\s*(.*)$", lines[i])
        m2 = re.match(r"^(\s*)(name|uses|run|if):\s*(.*)$", lines[i])
        if m:
            steps.append({})
            indent, key, value = len(m.group(1)) + 2, m.group(2), m.group(3)
        elif m2 and steps and len(m2.group(1)) == steps[-1].get("_indent", -1):
            indent, key, value = len(m2.group(1)), m2.group(2), m2.group(3)
        else:
            i += 1
            continue
        steps[-1]["_indent"] = indent  # type: ignore[assignment]
        if value.strip() in ("|", ">"):
            block = []
            i += 1
            while i < len(lines) and (not lines[i].strip() or _indent_of(lines[i]) > indent):
                block.append(lines[i])
                i += 1
            base = min(_indent_of(b) for b in block if b.strip())
            # literal block: common indentation removed, relative indentation kept
            steps[-1][key] = "\n".join(b[base:] for b in block).rstrip("\n") + "\n"
            continue
        steps[-1][key] = value.split(" #")[0].strip().strip('"')
        i += 1
    for s in steps:
        s.pop("_indent", None)
    return steps


def _indent_of(line: str) -> int:
    return len(line) - len(line.lstrip())


def _load() -> tuple[dict | None, list[dict]]:
    text = RECIPE.read_text()
    try:
        import yaml
    except ImportError:
        return None, _minimal_steps(text)
    doc = yaml.safe_load(text)
    steps = [s for job in doc["jobs"].values() for s in job["steps"]]
    return doc, steps


def _commands(run: str) -> list[list[str]]:
    """Each pgt-check invocation in a ``run`` script, as argv after the program name."""
    joined = re.sub(r"\\\n\s*", " ", run)
    out = []
    for line in joined.splitlines():
        line = line.split("||")[0].strip()
        line = re.sub(r"\$\{\{\s*env\.(\w+)\s*\}\}", r"$\1", line)
        tokens = shlex.split(line, comments=True)
        if tokens[:1] == ["pgt-check"]:
            out.append(tokens[1:])
        elif tokens[:3] == ["python", "-m", "pgt_check"]:
            out.append(tokens[3:])
    return out


def _help(*args: str) -> str:
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
    }
    res = subprocess.run(
        [sys.executable, "-m", "pgt_check", *args, "--help"],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert res.returncode == 0, res.stderr
    return res.stdout


@pytest.fixture(params=["pyyaml", "minimal"])
def parser(request, monkeypatch):
    """Run a test with PyYAML and again with the fallback parser (PyYAML hidden)."""
    if request.param == "pyyaml":
        pytest.importorskip("yaml")
    else:
        monkeypatch.setitem(sys.modules, "yaml", None)
    return request.param


def test_recipe_is_a_workflow_with_the_documented_steps(parser):
    doc, steps = _load()
    assert (doc is None) == (parser == "minimal")
    if doc is not None:
        assert doc["name"] and "jobs" in doc
        triggers = doc.get("on", doc.get(True))  # YAML 1.1 reads a bare `on` as True
        assert "pull_request" in triggers and "push" in triggers
    uses = [s.get("uses", "") for s in steps]
    runs = "\n".join(s.get("run", "") for s in steps)
    assert any(u.startswith("actions/checkout@") for u in uses)
    assert any(u.startswith("actions/setup-python@") for u in uses)
    assert any(u.startswith("actions/cache@") for u in uses), "pip cache"
    # apt packages for EGL rendering
    apt = re.search(r"apt-get install[^\n]*", re.sub(r"\\\n\s*", " ", runs))
    assert apt and EGL_PACKAGES <= set(apt.group(0).split())
    # the report is uploaded and the JUnit file published even when the gate fails
    upload = next(s for s in steps if s.get("uses", "").startswith("actions/upload-artifact@"))
    assert upload.get("if") == "always()"
    if doc is not None:
        assert "report.html" in upload["with"]["path"]
        publish = next(s for s in steps if "junit" in str(s.get("with", {})).lower())
        assert publish.get("if") == "always()" and "junit.xml" in publish["with"]["files"]
    assert _commands(runs), "no pgt-check command in the recipe"


def test_recipe_commands_use_existing_flags(parser):
    _, steps = _load()
    commands = [c for s in steps for c in _commands(s.get("run", ""))]
    gate = [c for c in commands if c and c[0] != "report" and "--version" not in c]
    report = [c[1:] for c in commands if c and c[0] == "report"]
    assert gate and report, commands
    for args, help_text in [(gate, _help()), (report, _help("report"))]:
        for argv in args:
            for flag in (t.split("=")[0] for t in argv if t.startswith("--")):
                assert re.search(rf"(?<![\w-]){re.escape(flag)}(?![\w-])", help_text), (
                    f"{flag} (used in {RECIPE.name}) is not in `pgt-check --help`"
                )
    # values are accepted too (choices, types): parse the gate commands with the real parser
    from pgt_check.commands import check

    for argv in gate:
        ns = check.build_parser().parse_args([a.replace("$", "") for a in argv])
        assert ns.mesh and ns.out


def test_commands_are_found_in_run_scripts():
    run = 'pgt-check "$T" --mesh m.ply \\\n  --out out --preset fast\npython -m pgt_check report out || true\n'
    assert _commands(run) == [
        ["$T", "--mesh", "m.ply", "--out", "out", "--preset", "fast"],
        ["report", "out"],
    ]


def test_minimal_parser_agrees_with_yaml():
    yaml = pytest.importorskip("yaml")
    text = RECIPE.read_text()
    full = [s for job in yaml.safe_load(text)["jobs"].values() for s in job["steps"]]
    minimal = _minimal_steps(text)
    for key in ("run", "uses", "if"):
        assert [s.get(key) for s in minimal] == [s.get(key) for s in full], key


def test_ci_runs_the_type_check_that_setup_installs():
    """.ci/run runs mypy (a failure fails CI, the tests still run), pyproject.toml states what
    it checks and how strictly, and the [dev] extra that scripts/setup.sh installs holds mypy."""
    import tomllib

    ci = (REPO / ".ci" / "run").read_text()
    lines = [ln.strip() for ln in ci.splitlines() if not ln.strip().startswith("#")]
    assert "python3 -m mypy" in lines
    assert lines.index("python3 -m mypy") < lines.index("python3 -m pytest")
    assert "mypy_rc" in ci and 'exit 1; fi' in ci.split("mypy_rc=$?")[1]
    project = tomllib.loads((REPO / "pyproject.toml").read_text())
    mypy = project["tool"]["mypy"]
    assert set(mypy["files"]) == {"pgt_check", "mariner_core"}
    strict = [o for o in mypy.get("overrides", []) if o.get("disallow_untyped_defs")]
    assert strict and all(o.get("disallow_any_generics") for o in strict)
    entries = {m for o in strict for m in o["module"]}
    assert {"pgt_check.runner", "pgt_check.measure.checker", "pgt_check.verdict.apply",
            "pgt_check.correct.frames", "pgt_check.report.outputs"} <= entries
    assert any(d.startswith("mypy") for d in project["project"]["optional-dependencies"]["dev"])
    setup = (REPO / "scripts" / "setup.sh").read_text()
    assert re.search(r"pip install[^\n]*-e \"\.\[[^\]]*\bdev\b", setup)
