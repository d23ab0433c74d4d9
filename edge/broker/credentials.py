"""Clear-text broker logins: the embedded broker's in the appliance's state directory, and ``broker-config``'s.

Both files have one layout (``[edge]``, ``[viewer]``, ``[rovers.<id>]`` tables with ``username`` and ``password``)
and are written by :func:`edge.private_files.write_private` (0600 from the first byte, replaced atomically). The
embedded broker's file, ``<state dir>/broker-credentials.toml``, is generated on the first start and reused after:
a rover configured later gets a login added, nobody's password changes. :func:`rover_login` is what provisioning
(``edge-ips flash``) and the rover simulator read.
"""

from __future__ import annotations

import fcntl
import json
import secrets
import tomllib
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from edge.broker.access import EDGE_USER, VIEWER_USER, Policy, check_names
from edge.errors import BrokerError
from edge.private_files import private_dir, write_private

CREDENTIALS_NAME = "broker-credentials.toml"
PASSWORD_BYTES = 18  # 144 random bits, 24 URL-safe characters


@dataclass(frozen=True)
class Login:
    username: str
    password: str = field(repr=False)


@dataclass(frozen=True)
class Credentials:
    """The edge's login, each rover's, and the read-only viewer's (optional)."""

    edge: Login
    rovers: Mapping[str, Login]
    viewer: Login | None = None

    def logins(self) -> list[Login]:
        return [self.edge, *self.rovers.values(), *([self.viewer] if self.viewer else [])]

    def passwords(self) -> dict[str, str]:
        """User name -> clear password, for hashing."""
        return {login.username: login.password for login in self.logins()}

    def policy(self, edge_id: str) -> Policy:
        return Policy(edge_id, tuple(self.rovers), edge_user=self.edge.username, viewer=self.viewer is not None)

    def to_toml(self, header: Sequence[str]) -> str:
        def table(name: str, login: Login) -> list[str]:
            return [f"[{name}]", f"username = {json.dumps(login.username)}", f"password = {json.dumps(login.password)}"]

        lines = [*(f"# {line}" for line in header), "", *table("edge", self.edge), ""]
        if self.viewer is not None:
            lines += [*table("viewer", self.viewer), ""]
        for rover, login in self.rovers.items():
            lines += [*table(f"rovers.{rover}", login), ""]
        return "\n".join(lines)


def new_password() -> str:
    return secrets.token_urlsafe(PASSWORD_BYTES)


def generate(
    rovers: Sequence[str],
    *,
    edge_user: str = EDGE_USER,
    viewer: bool = True,
    passwords: Mapping[str, str] | None = None,
) -> Credentials:
    """Random logins (or the ones given in ``passwords``, user -> password) for the edge, each rover, the viewer."""
    check_names(edge_user, rovers)
    given = passwords or {}

    def login(user: str) -> Login:
        return Login(user, given.get(user) or new_password())

    return Credentials(
        edge=login(edge_user),
        rovers={rover: login(rover) for rover in rovers},
        viewer=login(VIEWER_USER) if viewer else None,
    )


def _login(table: object, where: str) -> Login:
    if not isinstance(table, dict):
        raise BrokerError(f"{where}: expected a table with username and password")
    username, password = table.get("username"), table.get("password")
    if not isinstance(username, str) or not isinstance(password, str) or not username or not password:
        raise BrokerError(f"{where}: username and password must be non-empty strings")
    return Login(username, password)


def read_credentials(path: Path) -> Credentials:
    """Parse a credentials file; :class:`BrokerError` naming the file and table when it is not one."""
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise BrokerError(f"{path}: cannot read the broker credentials ({exc.strerror})") from exc
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise BrokerError(f"{path}: not a broker credentials file ({exc})") from exc
    rovers = data.get("rovers", {})
    if not isinstance(rovers, dict):
        raise BrokerError(f"{path}: rovers: expected [rovers.<id>] tables")
    credentials = Credentials(
        edge=_login(data.get("edge"), f"{path}: [edge]"),
        rovers={rover: _login(table, f"{path}: [rovers.{rover}]") for rover, table in rovers.items()},
        viewer=_login(data["viewer"], f"{path}: [viewer]") if "viewer" in data else None,
    )
    for rover, login in credentials.rovers.items():
        if login.username != rover:
            raise BrokerError(f"{path}: [rovers.{rover}]: the user name must be the rover id")
    try:
        check_names(credentials.edge.username, list(credentials.rovers))
    except BrokerError as exc:
        raise BrokerError(f"{path}: {exc}") from None
    return credentials


# -- the embedded broker's file in the state directory ------------------------------------------------------------
STATE_HEADER = (
    "Logins of the embedded MQTT broker, generated by `edge-ips start` and reused after. Keep secret (mode 600).",
    "The edge uses [edge]; each rover's [rovers.<id>] goes into its flash bundle (edge-ips flash);",
    "[viewer] may read every ips/v1 topic and publish nothing.",
)


def credentials_path(state_dir: Path) -> Path:
    return state_dir / CREDENTIALS_NAME


@contextmanager
def _locked(state_dir: Path) -> Iterator[None]:
    # Two processes starting at once (the service and a `flash`) must not each generate their own logins.
    with open(private_dir(state_dir) / f".{CREDENTIALS_NAME}.lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def ensure_credentials(state_dir: Path, rovers: Sequence[str]) -> Credentials:
    """The state directory's logins, created on the first call; a rover not in the file yet gets a login added."""
    path = credentials_path(state_dir)
    try:
        with _locked(state_dir):
            if not path.exists():
                credentials = generate(rovers)
            else:
                known = read_credentials(path)
                missing = [r for r in rovers if r not in known.rovers]
                if not missing and known.viewer is not None:
                    return known
                added = generate(missing, edge_user=known.edge.username)
                credentials = Credentials(
                    edge=known.edge,
                    rovers={**known.rovers, **added.rovers},
                    viewer=known.viewer or added.viewer,
                )
            write_private(path, credentials.to_toml(STATE_HEADER))
    except OSError as exc:
        raise BrokerError(
            f"{path}: cannot write the embedded broker's credentials ({exc.strerror}); set edge.state_dir to a "
            "writable directory"
        ) from exc
    return credentials


def rover_login(state_dir: Path, rover: str) -> Login | None:
    """The rover's login from the state directory's credentials (None when there is no file or no such rover)."""
    path = credentials_path(state_dir)
    if not path.exists():
        return None
    return read_credentials(path).rovers.get(rover)
