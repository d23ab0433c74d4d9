#!/usr/bin/env python3
"""Flash and provision a rover: ``python tools/flash.py --port /dev/ttyUSB0 --rover red [--firmware BIN] [--erase]``.

The same as ``edge-ips flash`` (see ``--help``); errors are one line with exit code 2.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from edge.cli.flash import flash

if __name__ == "__main__":
    flash.main(sys.argv[1:], prog_name="tools/flash.py")
