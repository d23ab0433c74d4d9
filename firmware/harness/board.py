"""An ESP8266 running MicroPython v1.28.0, as far as the rover firmware and the flash tool can tell.

:class:`Board` runs the repository's firmware (CPython, host stand-ins for ``machine`` and ``network``, umqtt.simple
on a :mod:`tests.mpy.fakenet` broker) in simulated time, and behaves like the chip where it matters here
(ports/esp8266 of v1.28.0):

- a hard reset runs ``boot.py`` then ``main.py`` from its filesystem (a directory), as ``__main__``; so does a soft
  reset (Ctrl-D at the REPL, :meth:`soft_reset`), which frees the Python heap but leaves the hardware as it was: pin
  levels, a started WDT, and PWM channels still pulsing (esppwm.c's state is C statics, outside the heap);
- ``machine.WDT()`` arms the SDK's soft watchdog for good: only ``feed()`` holds it off, not the REPL, not a soft reset
  (``machine_wdt.c`` sets ``ets_loop_dont_feed_sw_wdt``); after 3.2 s without a feed the chip resets, wherever it is;
- the program runs until Ctrl-C (a KeyboardInterrupt at its next wait, as the port raises it) or a reset; at the REPL
  nothing runs and time passes;
- :meth:`mpremote` takes the argv the flash tool would run (``connect P exec ... + fs cp ... + romfs deploy ... +
  reset``) and does what mpremote does: Ctrl-C, raw REPL with a soft reset (``boot.py`` again, not ``main.py``), each
  command taking the time a 115200-baud link needs; a reset under it cuts the session (non-zero exit status).

The program runs in its own thread, in lockstep with the caller: only one of them advances the clock at a time, so a
run is as deterministic as the firmware.
"""

from __future__ import annotations

import builtins
import io
import os
import subprocess
import sys
import threading
import types
from collections.abc import Sequence
from contextlib import redirect_stdout
from pathlib import Path
from typing import Any

from firmware.harness.runner import firmware_module, host_module, mpy_driver

WDT_MS = 3200  # the SDK's soft watchdog: a 1.6 s timer, reset at the second tick without a feed
BAUD_BYTES_S = 11520  # 115200 baud
RAW_REPL_MS = 300  # Ctrl-C, raw REPL, soft reset
EXEC_MS = 50
GUARD_MS = 10000  # mpremote gives up entering the raw REPL after this long


class BoardReset(BaseException):
    """The chip reset under the running program (a watchdog, machine.reset())."""


class SessionCut(Exception):
    """An mpremote session cut off by a reset of the board."""


class Board:
    """One board; ``root`` is its filesystem. Create it, put files in ``root``, then :meth:`power_on`."""

    def __init__(
        self,
        root: Path,
        version: str = "1.28.0",
        romfs: bool = True,
        fail_pwm: bool = False,
        failing_imports: dict[str, Exception] | None = None,
    ) -> None:
        self.root = root
        self.failing_imports = dict(failing_imports or {})  # module -> what importing it raises (a broken ROMFS)
        self.version = version
        self.has_romfs = romfs
        self.fail_pwm = fail_pwm
        fakenet = mpy_driver("fakenet")
        self.machine = host_module("machine")
        self.clock = fakenet.Clock()
        self.broker = fakenet.Broker(self.clock)
        self.net = fakenet.SocketModule(self.broker)
        self.romfs: bytes | None = None
        self.pwm_writes: list[tuple[int, int, int]] = []  # (ms, gpio, duty) for every PWM duty written
        self.pins: dict[int, int | None] = {}  # gpio -> level driven (None: input)
        self.boots = 0
        self.resets = 0
        self.wdt_fed: int | None = None  # None: no watchdog armed
        self.state = "off"  # "running" (boot.py/main.py), "repl"
        self.output: list[str] = []  # how the program ended, each time
        self.console = io.StringIO()  # what the board printed (its UART)
        self.dangling_timers = 0  # machine.Timer still armed when the Python heap went (a crash on the chip)
        self._thread: threading.Thread | None = None
        self._turn = "caller"
        self._cv = threading.Condition()
        self._hold = 0
        self._reset_pending = False
        self._in_session = False
        self._saved: tuple[Any, ...] = ()
        self.clock.watchers.append(self._watch)

    # -- set-up ------------------------------------------------------------------------------------------------------
    def __enter__(self) -> Board:
        app, link, simple = firmware_module("app"), firmware_module("link"), sys.modules["umqtt.simple"]
        self._saved = (app.time, link.time, simple.socket, self.machine.board, os.getcwd())
        app.time = link.time = self.clock
        simple.socket = self.net
        self.machine.board = self
        self.machine.power_on()
        os.chdir(self.root)  # main.py's app.run() opens "config.json", relative to the board's filesystem
        sys.stdout = _Uart(self, sys.stdout)
        return self

    def __exit__(self, *exc: object) -> None:
        try:
            self._stop_program()
        finally:
            app, link, simple = firmware_module("app"), firmware_module("link"), sys.modules["umqtt.simple"]
            app.time, link.time, simple.socket, self.machine.board, cwd = self._saved
            os.chdir(cwd)
            if isinstance(sys.stdout, _Uart):
                sys.stdout = sys.stdout.host
            self.machine.power_on()

    def power_on(self) -> None:
        self._start_program()

    def soft_reset(self) -> None:
        """Ctrl-D at the REPL: boot.py and main.py again, on the hardware as the last program left it."""
        if self._thread is not None and self._thread.is_alive():
            raise RuntimeError("Ctrl-D is a soft reset only at the REPL; the program is running")
        self._start_program(hard=False)

    # -- what the machine stand-in reports -------------------------------------------------------------------------
    def pin_set(self, gpio: int, level: int | None) -> None:
        self.pins[gpio] = level

    def pwm_set(self, gpio: int, duty: int) -> None:
        if self.fail_pwm:
            raise OSError("PWM hardware fault")
        self.pwm_writes.append((self.clock.now, gpio, duty))

    def wdt_start(self) -> None:
        self.wdt_fed = self.clock.now

    def wdt_feed(self) -> None:
        self.wdt_fed = self.clock.now

    def hard_reset(self) -> None:
        self._cut_network()
        raise BoardReset()

    # -- time --------------------------------------------------------------------------------------------------------
    def _watch(self, now: int) -> None:
        if self.wdt_fed is not None and now - self.wdt_fed > WDT_MS:
            self.wdt_fed = None
            self.resets += 1
            self._reset_pending = True
            self._cut_network()
            if threading.current_thread() is self._thread:
                raise BoardReset()
            if self._in_session:
                raise SessionCut("the board reset (watchdog)")
        if threading.current_thread() is self._thread and now >= self._hold:
            self._yield()

    def run(self, ms: int) -> None:
        """Let ``ms`` of simulated time pass with the board doing whatever it does."""
        end = self.clock.now + ms
        while self.clock.now < end:
            if self._reset_pending:
                self._start_program()
            if self._thread is not None and self._thread.is_alive():
                self._give(end)
            else:
                self.clock.tick()

    def _give(self, until: int) -> None:
        # Hand the clock to the program until it holds at `until` or ends.
        with self._cv:
            self._hold = until
            self._turn = "board"
            self._cv.notify_all()
            self._cv.wait_for(lambda: self._turn == "caller")

    def _yield(self) -> None:
        with self._cv:
            self._turn = "caller"
            self._cv.notify_all()
            self._cv.wait_for(lambda: self._turn == "board")

    # -- the program -----------------------------------------------------------------------------------------------
    def _start_program(self, hard: bool = True) -> None:
        self._stop_program()
        self._reset_pending = False
        self._cut_network()
        self._heap_gone()
        if hard:
            self.wdt_fed = None  # a hard reset clears the watchdog, the pins and the PWM
            self.pins = {}
            self.machine.power_on()
        self.boots += 1
        self.state = "running"
        self._thread = threading.Thread(target=self._program, daemon=True)
        with self._cv:
            self._turn = "board"
            self._hold = self.clock.now
        self._thread.start()
        with self._cv:
            self._cv.wait_for(lambda: self._turn == "caller")

    def _program(self) -> None:
        with self._cv:
            self._cv.wait_for(lambda: self._turn == "board")
        try:
            self._exec_file("boot.py")
            self._exec_file("main.py")
        except KeyboardInterrupt:
            self.output.append("KeyboardInterrupt")
        except BoardReset:
            self._reset_pending = True
        except Exception as e:
            self.output.append(f"main.py raised {e!r}")
        finally:
            self.state = "repl"
            with self._cv:
                self._turn = "caller"
                self._cv.notify_all()

    def _stop_program(self) -> None:
        thread = self._thread
        if thread is not None and thread.is_alive():
            self.clock.interrupt_at = self.clock.now  # Ctrl-C; a program that ignores it is cut by the guard
            self._give(self.clock.now + GUARD_MS)
            if thread.is_alive():
                raise RuntimeError("the board's program did not stop")
        self._thread = None

    def _cut_network(self) -> None:
        # The chip's TCP connection dies with it, without a goodbye.
        if self.broker.conn is not None:
            self.broker.conn.open = False
            self.broker.conn = None

    def _heap_gone(self) -> None:
        # A reset (hard or soft) frees every Python object; an armed machine.Timer would fire into freed memory.
        self.dangling_timers += len(self.machine._timers)
        self.machine.stop_timers()

    def _exec_file(self, name: str) -> None:
        path = self.root / name
        if not path.exists():
            return
        namespace = {"__name__": "__main__", "__builtins__": self._builtins()}
        exec(compile(path.read_text(), name, "exec"), namespace)

    # -- the board's side of the REPL -----------------------------------------------------------------------------
    def _builtins(self) -> dict[str, Any]:
        own = {
            "time": self.clock,
            "machine": self.machine,
            "os": _BoardOs(self.root),
            "sys": types.SimpleNamespace(implementation=types.SimpleNamespace(version=self._version())),
            "vfs": types.SimpleNamespace(rom_ioctl=object()) if self.has_romfs else types.SimpleNamespace(),
        }
        real_import = builtins.__import__

        def board_import(name: str, *args: Any, **kwargs: Any) -> Any:
            if name in self.failing_imports:
                raise self.failing_imports[name]
            return own[name] if name in own else real_import(name, *args, **kwargs)

        return {**builtins.__dict__, "__import__": board_import}

    def _version(self) -> tuple[int | str, ...]:
        return (*(int(v) for v in self.version.split(".")), "")

    # -- mpremote ------------------------------------------------------------------------------------------------
    def mpremote(self, argv: Sequence[str]) -> subprocess.CompletedProcess[str]:
        """Run what ``python -m mpremote connect PORT ...`` would, against this board."""
        args = list(argv[argv.index("connect") + 2 :])
        commands: list[list[str]] = [[]]
        for a in args:
            if a == "+":
                commands.append([])
            else:
                commands[-1].append(a)
        out = io.StringIO()
        self._in_session = True
        try:
            self._enter_raw_repl()
            for cmd in commands:
                self._command(cmd, out)
        except SessionCut as e:
            return subprocess.CompletedProcess(list(argv), 1, out.getvalue(), f"mpremote.transport.TransportError: {e}")
        finally:
            self._in_session = False
        return subprocess.CompletedProcess(list(argv), 0, out.getvalue(), "")

    def _spend(self, ms: int) -> None:
        for _ in range(ms):
            self.clock.tick()

    def _enter_raw_repl(self) -> None:
        if self._reset_pending:
            self._start_program()
        thread = self._thread
        if thread is not None and thread.is_alive():
            self.clock.interrupt_at = self.clock.now  # mpremote's Ctrl-C
            self._give(self.clock.now + GUARD_MS)
            if self._reset_pending:
                raise SessionCut("the board reset while stopping its program")
            if thread.is_alive():
                raise SessionCut("could not enter raw repl")
        self._thread = None
        self._spend(RAW_REPL_MS)
        self._heap_gone()  # the soft reset of the raw REPL
        self._exec_file("boot.py")

    def _command(self, cmd: list[str], out: io.StringIO) -> None:
        if cmd[0] == "exec":
            self._spend(EXEC_MS + len(cmd[1]) * 1000 // BAUD_BYTES_S)
            with redirect_stdout(out):
                try:
                    exec(cmd[1], {"__name__": "__main__", "__builtins__": self._builtins()})
                except BoardReset:
                    self._reset_pending = True
                    self._start_program()
        elif cmd[:2] == ["fs", "cp"]:
            data = Path(cmd[2]).read_bytes()
            self._spend(100 + 2 * len(data) * 1000 // BAUD_BYTES_S)  # raw-paste, hex
            (self.root / cmd[3].lstrip(":")).write_bytes(data)
        elif cmd[:2] == ["romfs", "deploy"]:
            if not self.has_romfs:
                raise SessionCut("romfs: no ROMFS partition (vfs.rom_ioctl missing)")
            data = Path(cmd[2]).read_bytes()
            self._spend(200 + 2 * len(data) * 1000 // BAUD_BYTES_S)
            self.romfs = data
        elif cmd == ["reset"]:
            self.resets += 1
            self._start_program()
        else:
            raise ValueError(f"the board stand-in does not know mpremote {cmd}")

    # -- what happened -----------------------------------------------------------------------------------------------
    def drove_after(self, t_ms: int) -> list[tuple[int, int, int]]:
        """PWM writes with a non-zero duty after ``t_ms``."""
        return [w for w in self.pwm_writes if w[0] > t_ms and w[2] > 0]

    def outputs(self) -> dict[int, int]:
        """What each driven GPIO puts out now, as a duty 0..1023 (a running PWM channel's, or 1023 for a pin held
        high): on a motor driver's enable pin, anything above 0 turns the wheel."""
        return dict(self.machine.outputs())


class _Uart(io.TextIOBase):
    """sys.stdout while a board runs: what its program prints goes to its console, the rest where it went."""

    def __init__(self, board: Board, host: Any) -> None:
        self.board = board
        self.host = host

    def write(self, text: str) -> int:
        if threading.current_thread() is self.board._thread:
            return self.board.console.write(text)
        return int(self.host.write(text))

    def flush(self) -> None:
        self.host.flush()


class _BoardOs:
    """``os`` on the board: its filesystem, rooted at the board's directory."""

    def __init__(self, root: Path) -> None:
        self.root = root

    def _path(self, name: str) -> Path:
        return self.root / name.lstrip("/")

    def listdir(self, path: str = "/") -> list[str]:
        return sorted(p.name for p in self._path(path).iterdir())

    def rename(self, a: str, b: str) -> None:
        src = self._path(a)
        if not src.exists():
            raise OSError(2, "ENOENT")
        src.rename(self._path(b))

    def remove(self, name: str) -> None:
        self._path(name).unlink()
