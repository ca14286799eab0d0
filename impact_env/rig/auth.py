"""The shared key that authenticates a rig session (:func:`impact_env.rig.protocol.tag`).

A key file holds the key as hexadecimal text (at least ``protocol.MIN_KEY`` bytes, i.e. 32 hex
digits; whitespace ignored), readable by its owner only: a file that its group or others may
read or write is refused, as ssh refuses such a private key, with the ``chmod 600`` to run.
``impact-env rig keygen FILE`` writes one (mode 0600) with 32 bytes from the OS's random source.
The same file goes to the target (``rig serve --key FILE``) and to the host (``ImpactCatchRig-v0(key=FILE)``,
``compare --rig ADDRESS --key FILE``).
"""

from __future__ import annotations

import os
import secrets
from pathlib import Path

from impact_env.rig import protocol


class KeyFileError(ValueError):
    """A key file that is missing, unreadable or malformed (the message names the option)."""


def load_key(path, option: str = "--key") -> bytes:
    """The key in the file at ``path``; raises :class:`KeyFileError` naming ``option`` when it is
    missing, unreadable, open to its group or others (POSIX), not hexadecimal or shorter than
    ``MIN_KEY`` bytes."""
    p = Path(os.fspath(path)).expanduser()
    try:
        _check_private(p, option)
        text = p.read_text(encoding="ascii")
    except FileNotFoundError:
        raise KeyFileError(f"{option} {p}: no such key file (make one with: impact-env rig keygen {p})") \
            from None
    except (OSError, UnicodeDecodeError) as exc:
        raise KeyFileError(f"{option} {p}: cannot read the key file: {exc}") from None
    digits = "".join(text.split())
    try:
        key = bytes.fromhex(digits)
    except ValueError:
        raise KeyFileError(f"{option} {p}: the key file must hold the key as hexadecimal digits "
                        f"(impact-env rig keygen writes one)") from None
    if len(key) < protocol.MIN_KEY:
        raise KeyFileError(f"{option} {p}: the key is {len(key)} B; at least {protocol.MIN_KEY} B "
                        f"({2 * protocol.MIN_KEY} hex digits) are needed")
    return key


def _check_private(p: Path, option: str) -> None:
    """A key file whose mode gives its group or others any access is refused (POSIX only: a
    Windows ACL has no such bits)."""
    if os.name != "posix":
        return
    mode = os.stat(p).st_mode & 0o777
    if mode & 0o077:
        raise KeyFileError(f"{option} {p}: the key file is open to its group or others (mode {mode:04o}); "
                           f"anyone who reads it can drive the rig.  Make it private: chmod 600 {p}")


def key_from(value, option: str = "key") -> bytes:
    """``value`` as a key: None -> b"" (no key), bytes as they are (checked), else a key file's path."""
    if value is None:
        return b""
    if isinstance(value, (bytes, bytearray)):
        if len(value) < protocol.MIN_KEY:
            raise KeyFileError(
                f"{option}: a key of {len(value)} B is too short; at least {protocol.MIN_KEY} B"
            )
        return bytes(value)
    return load_key(value, option)


def write_key(path, nbytes: int = 32) -> Path:
    """Write a new random key (``nbytes`` bytes, hexadecimal) to ``path``, mode 0600; refuses to
    overwrite an existing file."""
    if nbytes < protocol.MIN_KEY:
        raise ValueError(f"nbytes = {nbytes} must be at least {protocol.MIN_KEY}")
    p = Path(os.fspath(path)).expanduser()
    fd = os.open(p, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    if os.name == "posix":
        os.fchmod(fd, 0o600)  # whatever the umask, the mode load_key asks for
    with os.fdopen(fd, "w", encoding="ascii") as fh:
        fh.write(secrets.token_hex(nbytes) + "\n")
    return p
