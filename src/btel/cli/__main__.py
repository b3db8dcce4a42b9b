"""``python -m btel.cli``: the ``btel`` command."""

from . import main

main()
