"""The tests mirror the source tree: every module of ``pgt_check``, ``mariner_core`` and
``pgt_eval`` has a test file of its name (``pgt_check/x/y.py`` -> ``tests/pgt_check/x/test_y.py``),
or an entry in ``tests/TESTED_BY.toml`` that names the test files covering it and says why it has
none of its own. Entries must point at existing test files, and an entry whose module gained its
own test file (or no longer exists) is stale."""

from __future__ import annotations

import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("pgt_check", "mariner_core", "pgt_eval")
TABLE = REPO / "tests" / "TESTED_BY.toml"
#: files that are not modules of their own (package markers, ``python -m`` entry points)
NOT_MODULES = {"__init__.py", "__main__.py"}


def modules() -> list[str]:
    """Repository-relative paths of the modules that need a test (see the module docstring)."""
    return sorted(
        p.relative_to(REPO).as_posix()
        for pkg in PACKAGES
        for p in (REPO / pkg).rglob("*.py")
        if p.name not in NOT_MODULES and "__pycache__" not in p.parts
    )


def own_test(module: str) -> Path:
    """The test file named after ``module``: ``tests/<its folder>/test_<its name>.py``."""
    path = Path(module)
    return REPO / "tests" / path.parent / f"test_{path.stem}.py"


def table() -> dict[str, dict]:
    with open(TABLE, "rb") as f:
        return tomllib.load(f)


def test_every_module_has_a_test_file_of_its_name_or_a_table_entry():
    entries = table()
    missing = [m for m in modules() if not own_test(m).is_file() and m not in entries]
    assert not missing, (
        f"modules with no test file of their name and no entry in {TABLE.name}: write "
        "tests/<folder>/test_<name>.py, or add an entry naming the tests that cover the module "
        "and why it has none of its own:\n  " + "\n  ".join(missing)
    )


def test_table_entries_name_existing_tests_and_a_reason():
    bad = []
    for module, entry in table().items():
        tests = entry.get("tests")
        reason = entry.get("reason", "")
        if set(entry) - {"tests", "reason"}:
            bad.append(f"{module}: unknown keys {sorted(set(entry) - {'tests', 'reason'})}")
        if not isinstance(reason, str) or not reason.strip():
            bad.append(f"{module}: no reason")
        if not isinstance(tests, list) or not tests:
            bad.append(f"{module}: no test files")
            continue
        for t in tests:
            path = REPO / t
            if not (t.startswith("tests/") and path.is_file() and path.name.startswith("test_")):
                bad.append(f"{module}: {t} is not an existing test file")
    assert not bad, f"{TABLE.name}:\n  " + "\n  ".join(bad)


def test_no_stale_table_entries():
    existing = set(modules())
    stale = []
    for module in table():
        if module not in existing:
            stale.append(f"{module}: no such module (moved or removed): drop the entry")
        elif own_test(module).is_file():
            stale.append(
                f"{module}: has its own test file {own_test(module).relative_to(REPO)}: drop the entry"
            )
    assert not stale, f"stale entries in {TABLE.name}:\n  " + "\n  ".join(stale)


def test_the_layout_rules_see_what_they_should():
    """The checks above cannot pass vacuously: the module list and the name rule are real."""
    found = modules()
    assert "pgt_check/measure/checker.py" in found and "mariner_core/train.py" in found
    assert not any(m.endswith(("__init__.py", "__main__.py")) for m in found)
    assert own_test("pgt_check/measure/checker.py") == (
        REPO / "tests/pgt_check/measure/test_checker.py"
    )
    assert own_test("pgt_check/measure/checker.py").is_file()
    assert own_test("mariner_core/train.py") == REPO / "tests/mariner_core/test_train.py"
