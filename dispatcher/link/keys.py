"""MAVLink signing keys: one secret per vehicle, in a key directory outside the scenario.

A key file is ``<dir>/<vehicle id>.key`` holding the 32-byte secret as 64 hexadecimal
digits (and a newline). Key files must be readable by their owner only, and owned by the
user agrifleet runs as or by root: a key that group or others can read, or that another
user owns (and so can replace), is refused, as ssh refuses such a private key.
:func:`write_keys` (the ``agrifleet keys`` command) makes a new random key per vehicle,
the directory mode 700 and each file mode 600. docs/link.md says how signing works end to
end, and docs/bridge.md how a real autopilot gets its key.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import pwd
import secrets
import stat
import tempfile
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING

from dispatcher.config.errors import ConfigError
from dispatcher.link.mavlink import SIGNING_KEY_BYTES

if TYPE_CHECKING:
    from dispatcher.config.scenario import Scenario

logger = logging.getLogger(__name__)

KEY_SUFFIX = ".key"


class SigningKeyError(ConfigError):
    """A key file that is missing, unreadable, readable by others, or not a key."""


def key_path(keys_dir: str | os.PathLike[str], vehicle_id: str) -> Path:
    return Path(keys_dir) / f"{vehicle_id}{KEY_SUFFIX}"


def read_key(keys_dir: str | os.PathLike[str], vehicle_id: str) -> bytes:
    """The signing key of ``vehicle_id``; :class:`SigningKeyError` names the file and what is
    wrong with it."""
    path = key_path(keys_dir, vehicle_id)
    refuse_unless_closed(path.parent, "the signing keys", SigningKeyError)
    try:
        status = path.stat()
    except FileNotFoundError:
        raise SigningKeyError(
            f"{path}: no signing key for vehicle {vehicle_id!r}; make keys with "
            f"`agrifleet keys SCENARIO --keys {keys_dir}`"
        ) from None
    except OSError as exc:
        raise SigningKeyError(f"{path}: cannot read the signing key: {exc.strerror}") from exc
    if not stat.S_ISREG(status.st_mode):  # a pipe would hang the read, a folder mislead
        kind = "a folder" if stat.S_ISDIR(status.st_mode) else "a pipe, socket or device"
        raise SigningKeyError(f"{path}: not a key file but {kind}")
    refuse_unless_private(status, path, f"the signing key of {vehicle_id!r}", SigningKeyError)
    try:
        raw = path.read_bytes()
    except OSError as exc:  # not readable by this user, a folder
        raise SigningKeyError(f"{path}: cannot read the signing key: {exc.strerror}") from exc
    try:
        text = raw.decode("ascii").strip()
        key = bytes.fromhex(text)
    except (UnicodeDecodeError, ValueError) as exc:
        raise SigningKeyError(
            f"{path}: not a signing key ({2 * SIGNING_KEY_BYTES} hexadecimal digits expected)"
        ) from exc
    if len(key) != SIGNING_KEY_BYTES:
        lines = len(text.split())
        raise SigningKeyError(
            f"{path}: a signing key is {2 * SIGNING_KEY_BYTES} hexadecimal digits, "
            f"found {2 * len(key)}" + (f" on {lines} lines (one key a file)" if lines > 1 else "")
        )
    if len(set(key)) == 1:
        # All zeros turns signing off on ArduPilot; any one byte over is a key anyone guesses.
        raise SigningKeyError(
            f"{path}: not a secret key (one byte, {key[0]:02x}, {SIGNING_KEY_BYTES} times); "
            f"make one with `agrifleet keys SCENARIO --keys {keys_dir} --replace`"
        )
    return key


PRIVATE_MODE = 0o600
"""A private file's mode: its owner's only, as ssh wants of a private key."""


def refuse_unless_private(
    status: os.stat_result, path: Path, what: str, error: type[ConfigError]
) -> None:
    """``error`` naming the file and the fix when group or others may read ``what``, or
    when it belongs to a user other than the one agrifleet runs as (or root), who could
    replace it with one of theirs (ssh's rules for a private key)."""
    mode = status.st_mode
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise error(
            f"{path}: {what} is open to group or others (mode {stat.S_IMODE(mode):03o}); "
            f"make it the owner's only: chmod 600 {path}"
        )
    foreign = _foreign_owner(status, path)
    if foreign:
        raise error(f"{path}: {what} belongs to {foreign}")


def _foreign_owner(status: os.stat_result, path: Path) -> str:
    """Whose ``path`` is, and the fix, when not the user agrifleet runs as nor root's
    (they could replace it); empty when it is theirs."""
    me = os.geteuid()
    if status.st_uid in (me, 0):
        return ""
    owner, runner = _user(status.st_uid), _user(me)
    return (
        f"{owner}, who could replace it, not to {runner} who runs agrifleet (or root): "
        f"chown {runner} {path}"
    )


def _user(uid: int) -> str:
    """A user's name, or its number when it has none here."""
    try:
        return pwd.getpwuid(uid).pw_name
    except KeyError:
        return str(uid)


def write_file(path: Path, data: bytes, mode: int) -> None:
    """``data`` into ``path`` whole or not at all (a temporary file renamed), with ``mode``
    whatever the umask. The temporary file is a new one of a name not known before (a
    fixed name, planted as a symlink by whoever could write in the folder, put the key into
    their file)."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.fchmod(fd, mode)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def private_folder(folder: Path, what: str, error: type[ConfigError]) -> None:
    """Make ``folder`` (mode 700), or refuse one that exists and that group or others may
    write in: whoever can could put their files in place of the keys."""
    folder.mkdir(mode=0o700, parents=True, exist_ok=True)
    refuse_unless_closed(folder, what, error)


def refuse_unless_closed(folder: Path, what: str, error: type[ConfigError]) -> None:
    """``error`` naming the folder and the fix when group or others may write in it, or it
    belongs to a user other than the one agrifleet runs as (or root): whoever can could
    rename their own file over a key in it (checked on reading too, not only on writing)."""
    try:
        status = folder.stat()
    except OSError:
        return  # the file in it is then missing, and said so
    if status.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        raise error(
            f"{folder}: the folder of {what} may be written by group or others (mode "
            f"{stat.S_IMODE(status.st_mode):03o}): `chmod 700 {folder}` first"
        )
    foreign = _foreign_owner(status, folder)
    if foreign:
        raise error(f"{folder}: the folder of {what} belongs to {foreign}")


def read_keys(keys_dir: str | os.PathLike[str], vehicle_ids: Iterable[str]) -> dict[str, bytes]:
    """Each vehicle's key (:func:`read_key`), no two alike: with one key for two vehicles,
    either's leaked key commands both, and neither's frames can be told from the other's."""
    keys: dict[str, bytes] = {}
    for vid in vehicle_ids:
        key = read_key(keys_dir, vid)
        same = next((other for other, k in keys.items() if k == key), None)
        if same is not None:
            raise SigningKeyError(
                f"{key_path(keys_dir, vid)}: the same key as {key_path(keys_dir, same)}; "
                "each vehicle needs its own (`agrifleet keys SCENARIO --keys DIR --replace` "
                "makes new ones)"
            )
        keys[vid] = key
    return keys


def write_keys(
    keys_dir: str | os.PathLike[str], vehicle_ids: Iterable[str], replace: bool = False
) -> list[Path]:
    """A new random key for each vehicle that has none (or for every one, ``replace``);
    the paths written. The directory is made mode 700, each file mode 600."""
    folder = Path(keys_dir)
    private_folder(folder, "the signing keys", SigningKeyError)
    written = []
    for vid in vehicle_ids:
        path = key_path(folder, vid)
        if path.exists() and not replace:
            continue
        key = secrets.token_bytes(SIGNING_KEY_BYTES).hex() + "\n"
        write_file(path, key.encode("ascii"), PRIVATE_MODE)
        written.append(path)
    return written


def add_signing_arguments(p: argparse.ArgumentParser) -> None:
    """``--keys DIR`` and ``--unsigned``, the same for every command that speaks MAVLink."""
    g = p.add_argument_group("MAVLink signing (docs/link.md)")
    g.add_argument(
        "--keys",
        metavar="DIR",
        help="the vehicles' signing keys, <vehicle id>.key each (default: the scenario's "
        "'keys'; make them with `agrifleet keys SCENARIO --keys DIR`)",
    )
    g.add_argument(
        "--unsigned",
        action="store_true",
        help="no MAVLink signing: anyone on the network can command the tractors "
        "(for a test bench, never on a farm)",
    )


def signing_keys(
    args: argparse.Namespace, scenario: Scenario, vehicle_ids: Iterable[str]
) -> dict[str, bytes] | None:
    """The keys of ``vehicle_ids`` as ``--keys``/``--unsigned`` and the scenario say: None
    for ``--unsigned``; :class:`SigningKeyError` when no key directory is given."""
    if getattr(args, "unsigned", False):
        if getattr(args, "keys", None):
            raise SigningKeyError(
                f"--unsigned and --keys {args.keys}: one or the other (signed with the keys, "
                "or not signed at all)"
            )
        logger.warning("MAVLink signing is off (--unsigned): anyone on the network can command")
        return None
    folder = getattr(args, "keys", None) or scenario.keys_dir
    if folder is None:
        raise SigningKeyError(
            f'{scenario.source}: no MAVLink signing keys: give --keys DIR or keys = "DIR" in '
            "the scenario (make them with `agrifleet keys SCENARIO --keys DIR`), or --unsigned "
            "to run without signing (anyone on the network could then command the tractors)"
        )
    return read_keys(folder, vehicle_ids)
