"""An ``.ssp`` archive unpacked into a temporary folder, within limits (members, bytes,
no member outside the folder), its FMUs checked before anything runs (``Archive``).
"""

from __future__ import annotations

import tempfile
import zipfile
from pathlib import Path

from delaycomp.errors import SspError
from delaycomp.formats.ssp.common import (
    SSD_NAME,
)
from delaycomp.formats.ssp.read import Foreign, System, read_system
from delaycomp.unpack import MAX_BYTES, MAX_MEMBERS, Budget, TooLarge, extract, measure

#: what an archive may unpack to, with the FMUs inside it: members and bytes (the sizes
#: the zips declare, which zipfile enforces while extracting; ``delaycomp.unpack``)
MAX_UNPACKED = MAX_BYTES


def _check_member_fmu(path: Path, where: str) -> None:
    """Refuse an FMU inside an archive that is not a zip with a readable
    modelDescription (one line, instead of fmpy's traceback at the first run)."""
    from fmpy import read_model_description

    try:
        with zipfile.ZipFile(path) as zf:
            if "modelDescription.xml" not in zf.namelist():
                raise SspError(f"{where} is not an FMU: it has no modelDescription.xml")
        md = read_model_description(str(path), validate=False)
    except SspError:
        raise
    except zipfile.BadZipFile:
        raise SspError(f"{where} is not an FMU: not a zip archive") from None
    except Exception as exc:  # noqa: BLE001 - any parse failure is a bad file
        raise SspError(f"{where} is not a readable FMU: {type(exc).__name__}: "
                       f"{str(exc).splitlines()[0] if str(exc) else ''}") from None
    if md.coSimulation is None:
        raise SspError(f"{where} is not a co-simulation FMU")


class Archive:
    """An ``.ssp`` archive unpacked into a temporary folder (a context manager)."""

    def __init__(self, path: str | Path, foreign: Foreign | None = None):
        self.path = Path(path)
        self.foreign = foreign
        self._tmp: tempfile.TemporaryDirectory | None = None
        self.folder: Path | None = None
        self.system: System | None = None

    def __enter__(self) -> Archive:
        if not self.path.is_file():
            raise SspError(f"{self.path.name}: no such file")
        self._tmp = tempfile.TemporaryDirectory(prefix="delaycomp-ssp-")
        self.folder = Path(self._tmp.name)
        # one budget for the archive and the FMUs inside it, each unpacked in turn
        self.budget = Budget(self.path.name, MAX_MEMBERS, MAX_UNPACKED)
        try:
            extract(self.path, self.folder, self.budget)
        except TooLarge as exc:
            self.close()
            raise SspError(f"{self.path.name}: {exc.reason}") from None
        except zipfile.BadZipFile:
            self.close()
            raise SspError(f"{self.path.name}: not an SSP archive (not a zip file)") from None
        except SspError:
            self.close()
            raise
        if not (self.folder / SSD_NAME).is_file():
            self.close()
            raise SspError(f"{self.path.name}: no {SSD_NAME} in the archive")
        try:
            self.system = read_system(self.folder / SSD_NAME, self.foreign)
            for inst, source in self.system.sources.items():
                if not (self.folder / source).is_file():
                    raise SspError(f"{self.path.name}: component {inst}: {source} is missing")
                where = f"{self.path.name}: component {inst}: {source}"
                _check_member_fmu(self.folder / source, where)
                try:  # counted in full: the run unpacks it in turn
                    measure(self.folder / source, self.budget, f"component {inst}: {source}")
                except TooLarge as exc:
                    raise SspError(f"{self.path.name}: {exc.reason}") from None
        except SspError:
            self.close()
            raise
        return self

    def fmu(self, instance: str) -> Path:
        """The unpacked FMU file of component ``instance`` (inside the ``with`` block)."""
        assert self.folder is not None and self.system is not None  # set by __enter__
        return self.folder / self.system.sources[instance]

    def fmus(self) -> dict[str, Path]:
        """Component name -> its unpacked FMU file, for every component of the system."""
        assert self.system is not None  # set by __enter__
        return {inst: self.fmu(inst) for inst in self.system.sources}

    def close(self) -> None:
        """Remove the temporary folder and what it holds (``__exit__`` calls it; a second
        call does nothing)."""
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    def __exit__(self, *exc) -> None:
        self.close()
