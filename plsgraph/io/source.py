"""Open any supported recording: the container type is told from the name and the first bytes."""

from __future__ import annotations

from pathlib import Path

from ..errors import RecordingError
from .base import DecodedEvents, RawMessage, ReadLog, Source, TopicInfo

__all__ = ["DecodedEvents", "RawMessage", "ReadLog", "Source", "TopicInfo", "open_source"]


def open_source(path: str | Path) -> Source:
    """Open an MCAP file, a ROS 1 ``.bag``, a ROS 2 ``.db3`` or a ROS 2 bag directory, an AEDAT4 file
    (``.aedat4``) or a Prophesee Metavision ``.raw`` file (EVT 2.0 / 3.0).

    A ``.db3`` without ``metadata.yaml`` beside it (or a bag folder without one) is read from its sqlite
    tables directly.
    """
    p = Path(path)
    if not p.exists():
        raise RecordingError(f"recording {p} does not exist")
    if p.is_file() and p.stat().st_size == 0:
        raise RecordingError(f"{p} is empty (0 bytes): nothing was recorded into it, or it was cut off at the start; "
                             "use the complete file")
    if p.is_dir() and not any(p.iterdir()):
        raise RecordingError(f"{p} is an empty folder, not a ROS 2 bag (a bag folder holds metadata.yaml and its "
                             ".db3 or .mcap files)")
    if p.is_dir() and not (p / "metadata.yaml").exists() and not any(p.glob("*.db3")):
        return _folder_without_bag(p)
    if p.is_dir() or p.suffix in (".bag", ".db3"):
        from .db3_reader import Db3Source, bare_db3_files

        bare = bare_db3_files(p)
        if bare is not None:
            return Db3Source(bare, name=p)
        from .rosbags_reader import open_bag

        try:
            src = open_bag(p)
        except RecordingError as exc:
            # A ROS 2 bag folder whose metadata.yaml is damaged (cut, empty, naming files that are not there): its
            # .db3 files are read directly, as when it has none, rather than refused.
            folder = p if p.is_dir() else p.parent
            files = sorted(folder.glob("*.db3")) if (folder / "metadata.yaml").exists() else []
            if not files:
                missing = _listed_but_missing(folder) if (folder / "metadata.yaml").exists() else []
                if missing:  # an MCAP-storage bag copied in part
                    raise RecordingError(
                        f"the bag {folder} is incomplete: its metadata.yaml lists {', '.join(missing)}, which "
                        f"{'is' if len(missing) == 1 else 'are'} not there; copy the whole bag folder (or give one "
                        "of its .mcap files itself to read only that part)") from None
                raise
            src = Db3Source(files, name=p)
            missing = _listed_but_missing(folder)
            if missing:
                src.log.warn(
                    f"the bag {folder} is incomplete: its metadata.yaml lists {', '.join(missing)}, which "
                    f"{'is' if len(missing) == 1 else 'are'} not there; only {', '.join(f.name for f in files)} "
                    "could be read, so part of the recording is missing (copy the whole bag folder)")
                return src
            why = (str(exc.__cause__ or exc).strip().splitlines() or ["unreadable"])[0]
            src.log.warn(f"{folder.name}/metadata.yaml could not be used ({why}); read its .db3 files directly "
                         "(topics and types from their own tables)")
            return src
        return _db3_if_metadata_disagrees(p, src)
    head = _head(p)
    if p.suffix == ".mcap" or head.startswith(b"\x89MCAP0\r\n"):
        from .mcap_reader import McapSource

        return McapSource(p)
    if p.suffix in (".aedat4", ".aedat") or head.startswith(b"#!AER-DAT"):
        from .aedat4 import Aedat4Source

        return Aedat4Source(p)
    if p.suffix == ".raw" or head.startswith(b"% "):
        from .prophesee import RawEventSource

        return RawEventSource(p)
    if p.suffix in (".zstd", ".zst", ".lz4", ".bz2", ".gz", ".xz"):
        raise RecordingError(
            f"{p} is a compressed file ({p.suffix[1:]}): decompress it first (e.g. `zstd -d {p.name}` for a ROS 2 bag "
            "written with file compression, or pass the bag's folder with its metadata.yaml, which rosbags reads "
            "compressed)")
    if p.suffix in (".hdf5", ".h5"):
        raise RecordingError(
            f"{p}: Metavision HDF5 event files are not supported (their ECF compression plugin has no maintained "
            "Python package); record RAW (.raw, Metavision's default) "
            "or write the events to a ROS bag or AEDAT4 instead"
        )
    raise RecordingError(
        f"cannot tell the container type of {p}: expected a .mcap file, a ROS 1 .bag, a ROS 2 .db3 "
        "or a ROS 2 bag directory, an AEDAT4 file (.aedat4) or a Prophesee .raw file"
    )


def _db3_if_metadata_disagrees(p: Path, src: Source) -> Source:
    """``src`` (a ROS 2 bag opened through its metadata.yaml), or, when the metadata names a topic's type otherwise
    than the bag's own .db3 tables do (an edited or mixed-up metadata.yaml: the topic's messages would be read as the
    wrong type, or not at all), the .db3 files read directly, with a warning naming the disagreement."""
    import sqlite3

    from .db3_reader import Db3Source
    from .messages import normalize_type

    folder = p if p.is_dir() else p.parent
    files = sorted(folder.glob("*.db3")) if (folder / "metadata.yaml").exists() else []
    theirs: dict[str, str] = {}
    for f in files:  # only the small topics table: the messages are not counted here
        try:
            con = sqlite3.connect(f"file:{f}?mode=ro", uri=True)
            try:
                theirs.update({str(n): normalize_type(str(t)) for n, t in con.execute("SELECT name, type FROM topics")})
            finally:
                con.close()
        except sqlite3.Error:
            return src  # the tables are what rosbags could not read either way: keep its reading
    said = src.topics()
    differ = sorted(t for t, i in said.items() if theirs.get(t) and i.msgtype != theirs[t])
    if not differ:
        return src
    own = Db3Source(files, name=p)
    own.log.warn(f"{folder.name}/metadata.yaml names the type of {', '.join(differ)} otherwise than the bag's .db3 "
                 f"(e.g. {said[differ[0]].msgtype} against {theirs[differ[0]]}); read the .db3 files directly, with "
                 "their own types")
    return own


def _listed_but_missing(folder: Path) -> list[str]:
    """The files a bag folder's metadata.yaml lists that are not in the folder (a bag copied in part)."""
    import yaml

    try:
        meta = yaml.safe_load((folder / "metadata.yaml").read_text())
        listed = meta["rosbag2_bagfile_information"]["relative_file_paths"]
    except (OSError, yaml.YAMLError, KeyError, TypeError):
        return []
    if not isinstance(listed, list):
        return []
    return [str(f) for f in listed if isinstance(f, str) and not (folder / f).exists()]


#: What a folder that is not a ROS 2 bag may hold that plsgraph reads as a recording.
_RECORDING_SUFFIXES = (".mcap", ".bag", ".raw", ".aedat4", ".aedat")


def _folder_without_bag(p: Path) -> Source:
    """A folder with neither metadata.yaml nor .db3 files: the one MCAP a bag folder kept when it lost its
    metadata is read (with a warning); a folder of several recordings or of none is refused, saying which."""
    recs = sorted(f for f in p.iterdir() if f.is_file() and f.suffix in _RECORDING_SUFFIXES)
    if len(recs) == 1 and recs[0].suffix == ".mcap":
        from .mcap_reader import McapSource

        src = McapSource(recs[0])
        src.log.warn(f"{p} has no metadata.yaml; read the one recording in it, {recs[0].name}")
        return src
    if recs:
        names = ", ".join(f.name for f in recs[:4]) + (", ..." if len(recs) > 4 else "")
        raise RecordingError(
            f"{p} is a folder of {len(recs)} recording{'s' if len(recs) > 1 else ''} ({names}), not a ROS 2 bag (a bag "
            "folder holds metadata.yaml); give one recording, or calibrate them all with 'plsgraph batch'"
            + ("; if they are the split files of one bag, restore its metadata.yaml ('ros2 bag reindex' on a copy)"
               if sum(f.stem.rsplit("_", 1)[-1].isdigit() for f in recs) > 1 else ""))
    raise RecordingError(f"{p} is a folder without a recording: no metadata.yaml (a ROS 2 bag) and no .db3, .mcap, "
                         ".bag, .raw or .aedat4 file in it")


def _head(p: Path) -> bytes:
    with open(p, "rb") as f:
        return f.read(16)
