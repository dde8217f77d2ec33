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
