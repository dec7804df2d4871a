"""Writes recon/cli/values.py: every library value a flag of ``recon`` shows (a default, a list of
choices), read from the library, so that ``recon COMMAND --help`` needs no torch. Run it after
changing such a value; tests/test_cli.py fails until the table matches the library.

    .venv/bin/python scripts/cli_values.py
"""
from pathlib import Path
from pprint import pformat

from recon.cli import recorded_values

OUT = Path(__file__).resolve().parent.parent / "recon" / "cli" / "values.py"
HEADER = ('"""The library values the flags show (recon.cli.parsing.known): written by\n'
          '``python scripts/cli_values.py``, checked against the library by tests/test_cli.py."""\n\n')

if __name__ == "__main__":
    values = recorded_values()
    OUT.write_text(HEADER + "VALUES = " + pformat(dict(sorted(values.items())), width=116, sort_dicts=False) + "\n")
    print(f"{OUT}: {len(values)} values")
