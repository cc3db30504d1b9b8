"""Archives (FMUs, SSPs) unpacked within limits, all the way down.

Every archive delaycomp unpacks, and every archive inside one that it will unpack in turn
(an FMU inside an SSP), is measured first from the sizes its zip directory declares, which
``zipfile`` enforces while extracting (a member that inflates beyond its declared size
fails its CRC check and is refused): at most ``MAX_MEMBERS`` files and
``MAX_BYTES`` bytes, counted together for an archive and the archives inside it that
will be unpacked, and no member outside the target folder. A request over the limits is
refused before anything is written.

Examples
--------
>>> import io, zipfile
>>> buf = io.BytesIO()
>>> with zipfile.ZipFile(buf, "w") as zf:
...     zf.writestr("modelDescription.xml", "<fmiModelDescription/>")
>>> Budget("x.fmu").charge(zipfile.ZipFile(buf).infolist(), "x.fmu")
>>> Budget("x.fmu", max_bytes=10).charge(zipfile.ZipFile(buf).infolist(), "x.fmu")
... # doctest: +ELLIPSIS
Traceback (most recent call last):
...
delaycomp.unpack.TooLarge: x.fmu: unpacks to 1 files of 22 bytes: at most 1000 files and ...
"""

from __future__ import annotations

import zipfile
from collections.abc import Callable, Iterable
from pathlib import Path, PurePosixPath

from delaycomp.errors import BadFileError

__all__ = ["MAX_BYTES", "MAX_MEMBERS", "Budget", "TooLarge", "extract", "measure"]

#: files an archive may unpack to, with the archives inside it that are unpacked too
MAX_MEMBERS = 1000
#: bytes an archive may unpack to, with the archives inside it that are unpacked too;
#: our archives hold a few FMUs of about 0.5 MB, a Modelica tool's FMU a few MB
MAX_BYTES = 512 * 2**20


class TooLarge(BadFileError):
    """An archive would unpack beyond the limits, or a member would leave its folder
    (one line naming the archive; the command line's exit status 2)."""


class Budget:
    """What one request may still unpack: members and bytes, shared by an archive and the
    archives inside it (``where``, the outermost archive, names the request)."""

    def __init__(self, where: str | Path, max_members: int = MAX_MEMBERS,
                 max_bytes: int = MAX_BYTES):
        self.where = Path(where)
        self.max_members, self.max_bytes = max_members, max_bytes
        self.members = 0
        self.bytes = 0

    def charge(self, infos: Iterable[zipfile.ZipInfo], what: str) -> None:
        """Count ``infos`` (members of the archive ``what``); ``TooLarge`` if the
        request goes over its limits, or a member's name leaves the folder."""
        infos = list(infos)
        for info in infos:
            _check_name(info.filename, what)
        self.members += len(infos)
        self.bytes += sum(i.file_size for i in infos)
        if self.members > self.max_members or self.bytes > self.max_bytes:
            inner = "" if what == self.where.name else f" (with {what})"
            raise TooLarge(self.where, f"unpacks to {self.members} files of {self.bytes} "
                                       f"bytes{inner}: at most {self.max_members} files and "
                                       f"{self.max_bytes} bytes are allowed")


def _check_name(name: str, what: str) -> None:
    """A member name that stays inside the folder it is unpacked into."""
    pure = PurePosixPath(name.replace("\\", "/"))
    if pure.is_absolute() or ".." in pure.parts or (pure.parts and ":" in pure.parts[0]):
        raise TooLarge(what, f"member {name!r} is not allowed: it leaves the archive")


def measure(path: str | Path, budget: Budget, what: str | None = None,
            include: Callable[[str], bool] | None = None) -> list[zipfile.ZipInfo]:
    """Charge ``budget`` with the members of the zip archive ``path`` that ``include``
    keeps (all by default); return them. A file that is not a zip raises
    ``zipfile.BadZipFile``."""
    with zipfile.ZipFile(path) as zf:
        infos = [i for i in zf.infolist() if include is None or include(i.filename)]
    budget.charge(infos, what or Path(path).name)
    return infos


def extract(path: str | Path, folder: str | Path, budget: Budget | None = None,
            include: Callable[[str], bool] | None = None) -> Path:
    """Unpack the members of ``path`` that ``include`` keeps into ``folder`` within
    ``budget`` (default: a fresh one named after the file); return ``folder``."""
    budget = budget or Budget(path)
    infos = measure(path, budget, include=include)
    folder = Path(folder)
    with zipfile.ZipFile(path) as zf:
        for info in infos:
            zf.extract(info, folder)
    return folder
