import ast
from pathlib import Path

IDENT = Path(__file__).resolve().parents[2] / "rtsid" / "ident"


def test_the_numerics_import_nothing_of_rtsid_but_errors_and_their_vocabulary():
    # DESIGN.md: rtsid/ident is pure numerics; streaming, I/O and config sit above it.
    # rtsid.verdicts (Reason, Flag) is the vocabulary of errors.WindowError, at the bottom too.
    offenders = []
    for path in sorted(IDENT.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = (
                [node.module or ""]
                if isinstance(node, ast.ImportFrom)
                else [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else []
            )
            for name in names:
                if name.startswith("rtsid") and not name.startswith(
                    ("rtsid.ident", "rtsid.errors", "rtsid.verdicts")
                ):
                    offenders.append(f"{path.name}: {name}")
    assert not offenders, offenders


def imported_modules(path):
    """The modules a file imports (``from X import y`` gives X and X.y)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
            names.update(f"{node.module}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
    return names


#: The window pipeline's steps, in order (rtsid/ident/window.py composes them).
PIPELINE_STEPS = ("options", "check", "analysis", "front", "fit", "assess")


def test_each_step_of_the_window_pipeline_imports_only_earlier_steps_never_the_driver():
    # issue 19: the driver (window.py) composes the steps; a step knows no later step, the
    # driver, the stream or the legacy criteria (which sit off the main path).
    later_or_outside = {"rtsid.ident.window", "rtsid.ident.stream", "rtsid.ident.legacy"}
    for index, step in enumerate(PIPELINE_STEPS):
        imported = imported_modules(IDENT / f"{step}.py")
        forbidden = later_or_outside | {f"rtsid.ident.{s}" for s in PIPELINE_STEPS[index + 1 :]}
        assert not imported & forbidden, (step, sorted(imported & forbidden))


def test_only_the_driver_reaches_the_legacy_criteria():
    importers = sorted(
        path.name
        for path in IDENT.glob("*.py")
        if path.name != "legacy.py" and "rtsid.ident.legacy" in imported_modules(path)
    )
    assert importers == ["window.py"]
