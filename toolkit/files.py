"""Reading and writing files safely: what every command and API function that touches disk uses.

Rules (docs/cli.md, "Files"):

* **Inputs** must be regular files: a folder, a FIFO, a socket or a device is refused before it
  is opened (reading a FIFO would block for ever, a device may never end).
* **Outputs** are written atomically: to a temporary file in the destination's folder, flushed,
  then renamed over the destination, so a reader never sees a half-written file and a failure
  (full disk, file-size limit, permission) leaves the old file untouched and no temporary file
  behind.  The new file gets the permissions a plain ``open(path, "w")`` would give it (``0666``
  less the umask), or keeps those of the file it replaces.  An output path that is a symbolic
  link is followed: the link stays, its target is replaced.
* An output is refused when it is a folder, a device, a FIFO or a socket, when its folder does
  not exist, or when it is one of the same command's inputs (compared after resolving links).
* JSON is written strictly (RFC 8259): NaN and ±∞ become ``null`` — never ``NaN`` or
  ``Infinity``, which strict parsers (JavaScript's ``JSON.parse``) refuse.

Every failure is a :class:`~tendonkit.errors.OutputError` (or ``DataError`` for inputs) whose
message names the path and the operating system's reason.
"""

from __future__ import annotations

import errno
import json
import math
import os
import stat
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from .errors import OutputError

__all__ = [
    "atomic_write",
    "check_input_file",
    "check_output_dir",
    "check_output_path",
    "json_safe",
    "prepare_output_dir",
    "write_json",
]


def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISSOCK(mode):
        return "a socket"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    return "not a regular file"


def check_input_file(path: str | Path, problems: list[str], what: str = "input") -> bool:
    """Append a problem unless ``path`` is an existing regular file (links followed)."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        problems.append(f"{what} {str(path)!r} does not exist.")
        return False
    except OSError as exc:
        problems.append(f"{what} {str(path)!r} cannot be read: {exc.strerror or exc}.")
        return False
    if not stat.S_ISREG(st.st_mode):
        problems.append(
            f"{what} {str(path)!r} is {_kind(st.st_mode)}; tendonkit reads regular files only."
        )
        return False
    return True


def same_file(a: str | Path, b: str | Path) -> bool:
    """Whether two paths name one file or folder (after resolving links; hard links too)."""
    a, b = Path(a), Path(b)
    try:
        return a.resolve() == b.resolve() or (a.exists() and b.exists() and a.samefile(b))
    except OSError:
        return False


def check_output_path(
    path: str | Path,
    inputs: Sequence[str | Path],
    problems: list[str],
    what: str = "output",
    creates: Sequence[str | Path | None] = (),
) -> None:
    """Append every reason why ``path`` cannot be written as an output file.

    Refused: one of ``inputs`` (after resolving links), a folder, a device, a FIFO, a socket,
    a path whose folder does not exist (nor is among the folders ``creates``, which the same
    command makes).  An existing regular file is replaced.
    """
    p = Path(path)
    for src in inputs:
        if same_file(p, Path(src)):
            problems.append(f"{what} {str(path)!r} is also an input; refusing to overwrite it.")
            break
    try:
        st = os.stat(p)  # follows links: the target is what would be replaced
    except FileNotFoundError:
        st = None
    except OSError as exc:
        problems.append(f"{what} {str(path)!r} cannot be written: {exc.strerror or exc}.")
        return
    if st is not None and not stat.S_ISREG(st.st_mode):
        problems.append(
            f"{what} {str(path)!r} is {_kind(st.st_mode)}; tendonkit writes regular files only."
        )
        return
    parent = p.resolve().parent
    made = {Path(c).resolve() for c in creates if c is not None}
    if not parent.is_dir() and parent not in made:
        problems.append(f"the folder of {what} {str(path)!r} does not exist.")


def check_output_dir(
    path: str | Path,
    inputs: Sequence[str | Path],
    problems: list[str],
    what: str = "output folder",
) -> None:
    """Append every reason why ``path`` cannot be used as an output folder (created on demand).

    Refused: an existing path that is not a folder, a folder among ``inputs``, a path whose
    parent folder does not exist (only the last level is created).
    """
    p = Path(path)
    if p.exists() and not p.is_dir():
        problems.append(f"{what} {str(path)!r} exists and is not a folder.")
        return
    for src in inputs:
        if same_file(p, Path(src)):
            problems.append(f"{what} {str(path)!r} is also an input.")
            return
    if not p.exists() and not p.resolve().parent.is_dir():
        problems.append(f"the parent folder of {what} {str(path)!r} does not exist.")


def prepare_output_dir(path: str | Path) -> Path:
    """Create the output folder checked by :func:`check_output_dir` (no error if it exists)."""
    p = Path(path)
    try:
        p.mkdir(exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot create folder {str(path)!r}: {_reason(exc)}.") from None
    return p


def _reason(exc: OSError) -> str:
    if exc.errno is not None:
        return os.strerror(exc.errno)
    return str(exc)


def _new_file_mode(target: Path) -> int:
    """Permissions for the replacement: the old file's, else 0666 less the umask."""
    try:
        return stat.S_IMODE(os.stat(target).st_mode)
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


def atomic_write(path: str | Path, write: Callable[[Path], Any]) -> Path:
    """Write ``path`` through a temporary file in its folder and rename it into place.

    ``write(tmp_path)`` writes the content.  A symbolic link at ``path`` is followed (the link
    stays, its target is replaced).  On any failure the temporary file is removed and the
    destination is untouched; operating-system failures (full disk, file-size limit,
    permissions) raise :class:`~tendonkit.errors.OutputError` naming ``path`` and the reason.

    Returns
    -------
    Path
        ``path`` as given.
    """
    given = Path(path)
    target = Path(os.path.realpath(given))
    problems: list[str] = []
    check_output_path(given, [], problems)
    if problems:
        raise OutputError("cannot write the output:", problems)
    mode = _new_file_mode(target)
    tmp: str | None = None
    try:
        fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.", suffix=".tmp")
        os.close(fd)
        write(Path(tmp))
        with open(tmp, "rb+") as fh:  # the data on disk before the rename
            os.fsync(fh.fileno())
        os.chmod(tmp, mode)
        os.replace(tmp, target)
        tmp = None
    except OSError as exc:
        raise OutputError(f"cannot write {str(given)!r}: {_reason(exc)}.") from None
    finally:
        if tmp is not None:
            try:
                os.unlink(tmp)
            except OSError as exc:
                if exc.errno != errno.ENOENT:
                    raise
    return given


def json_safe(value: Any) -> Any:
    """``value`` with every non-finite float replaced by ``None`` (strict JSON), recursively."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if hasattr(value, "tolist") and callable(value.tolist):  # numpy scalars and arrays
        return json_safe(value.tolist())
    return value


def write_json(path: str | Path, data: Any) -> Path:
    """Write ``data`` as strict JSON (NaN and ±∞ as ``null``), atomically."""
    text = json.dumps(json_safe(data), indent=2, allow_nan=False)
    return atomic_write(path, lambda p: p.write_text(text + "\n", encoding="utf-8"))
