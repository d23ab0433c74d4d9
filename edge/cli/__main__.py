"""``python -m edge.cli``: the ``edge-ips`` command of this checkout."""

from edge.cli import main

main()
