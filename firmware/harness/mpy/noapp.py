# Driver: the flash bundle's boot.py and main.py when main.py's `import app` fails (a ROMFS image without app.mpy,
# or no heap left to import it), inside MicroPython. `fail_dir` holds an app.py that raises, put first on sys.path.
# Prints what main.py printed and each motor pin's output, as JSON.
import json
import sys

import machine


class _Console:
    def __init__(self):
        self.lines = []

    def write(self, text):
        self.lines.append(text)


def main(bundle, fail_dir, pins):
    machine.power_on()
    sys.path.insert(0, fail_dir)
    with open(bundle + "/boot.py") as f:
        exec(f.read(), {"__name__": "__main__"})
    console = _Console()
    ns = {"__name__": "__main__", "print": lambda *a: console.write(" ".join(str(x) for x in a))}
    raised = None
    try:
        with open(bundle + "/main.py") as f:
            exec(f.read(), ns)
    except BaseException as e:  # noqa: BLE001 - what the REPL would show as a traceback
        raised = repr(e)
    out = machine.outputs()
    print(json.dumps({"printed": console.lines, "raised": raised, "outputs": [out.get(p) for p in pins]}))
