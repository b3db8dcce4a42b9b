"""Error messages in the command line's words.

The library names its own API in messages (``fit_on=``, ``key=``, ``dtype='float16'``,
``BTELocalizer.fit(...)``): right for a Python user, wrong for someone typing ``btel``. When an
error reaches the command line its message is rewritten here, phrase by phrase, into the options
that do the same thing. A phrase not listed is shown as it is.
"""

from __future__ import annotations

import re

#: (library phrase, command-line phrase): regular expressions, applied in order.
CLI_WORDS: tuple[tuple[str, str], ...] = (
    (r"Train one with BTELocalizer\.fit\(\.\.\.\)\.save\(path\) or `btel train`",
     "Train one with `btel train DB -o MODEL`"),
    (r"pass fit_on=<map images>", "pass --fit-on MAP_IMAGES_DIR"),
    (r"\bfit_on=", "--fit-on "),
    (r"use dtype='float16'", "use --param dtype=float16"),
    (r"(\S+\.npz):(\S+) on the command line, key='[^']*' in Python", r"\1:\2"),
    (r"choose one with key=\.?", "choose one with FILE.npz:KEY."),
    (r"\bn_regions='auto'", "--regions auto"),
    (r"Pass overwrite=True \(CLI: --overwrite\)", "Give --overwrite"),
    (r"pass overwrite=True \(CLI: --overwrite\)", "give --overwrite"),
)


def cli_message(message: str) -> str:
    """``message`` with every library phrase of :data:`CLI_WORDS` replaced by its command-line phrase."""
    for pattern, replacement in CLI_WORDS:
        message = re.sub(pattern, replacement, message)
    return message


_BARE_NUMBER = re.compile(r"\s*(\d+(?:\.\d+)?)\s*")


def unitless_budget_hint(text: str) -> str | None:
    """For a budget written without a unit and under 1000 (``32``), the budget it most likely means
    (``32KB``); else None. Such a number of bytes holds no useful map, so it is taken for a missing
    unit; ``32B`` says bytes explicitly, and a unitless number from 1000 up is read as bytes."""
    match = _BARE_NUMBER.fullmatch(text)
    if match is None or float(match.group(1)) >= 1000:
        return None
    return f"{match.group(1)}KB"
