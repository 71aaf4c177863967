"""msx's cache: one folder, one way to write an entry and one way to check it.

Where: ``$MSX_CACHE_DIR``, else ``$XDG_CACHE_HOME/msx``, else ``~/.cache/msx`` (:func:`root`), one sub-folder
per kind (:data:`KINDS`). Deleting any of it only costs recomputing (``msx cache --clear``).

Every entry is keyed by what it was computed from (a hash of its inputs in its name, or, for files whose name
is fixed, recorded beside it) and written atomically: the data goes to a temporary name in the entry's own
folder and is renamed into place (``os.replace``: the entry is whole or absent), then a small record beside
it, ``.<name>.msx`` (JSON: size, SHA-256, key), is written the same way. A folder entry (a copy of the
scenes) is built in a temporary folder, with a manifest ``.msx-entry`` listing every file's size and SHA-256,
and renamed into place.

Reading checks the bytes against the record. An entry that does not match it (truncated, corrupted, made from
other inputs, or without a record: an interrupted write or an older msx) is reported on stderr in one line,
deleted, and the caller recomputes it.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
import uuid
from pathlib import Path

KINDS = {
    "references": "converged reference renders of msx compare",
    "simulations": "microgeometry ray-tracing results of msx compare",
    "native": "compiled native plugins (and remembered build failures)",
    "scenes": "copies of the shipped scenes with their assets (read-only installs)",
    "assets": "generated scene assets for scenes whose own folder is read-only",
}
MANIFEST = ".msx-entry"


def root() -> Path:
    """msx's cache folder: $MSX_CACHE_DIR, else $XDG_CACHE_HOME/msx, else ~/.cache/msx."""
    base = os.environ.get("MSX_CACHE_DIR")
    if base:
        return Path(base).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg).expanduser() if xdg else Path.home() / ".cache") / "msx"


def folder(kind: str) -> Path:
    """The folder of one kind of entry (not created)."""
    if kind not in KINDS:
        raise ValueError(f"unknown cache kind {kind!r}; kinds: {', '.join(KINDS)}")
    return root() / kind


def record_path(path: Path) -> Path:
    path = Path(path)
    return path.with_name(f".{path.name}.msx")


def _digest(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _tmp_name(path: Path) -> Path:
    """A temporary name in `path`'s folder, keeping its suffix (numpy and Mitsuba choose the format by it)."""
    return path.with_name(f".{path.stem}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp{path.suffix}")


def _write_json(path: Path, data: dict):
    tmp = _tmp_name(path)
    try:
        tmp.write_text(json.dumps(data, sort_keys=True))
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def report(path, reason: str, action: str = "recomputing it"):
    """The one line on stderr for an entry that cannot be used."""
    try:
        sys.stderr.write(f"msx: {path} is {reason}; {action}\n")
        sys.stderr.flush()
    except (OSError, ValueError):
        pass


def commit_file(tmp: Path, path: Path, key=None):
    """Moves the finished temporary file `tmp` (in `path`'s folder) to `path` and records its size and
    checksum (and `key`, what it was computed from) beside it."""
    tmp, path = Path(tmp), Path(path)
    record = {"size": tmp.stat().st_size, "sha256": _digest(tmp), "key": key}
    record_path(path).unlink(missing_ok=True)  # never a new record beside old bytes, nor the reverse
    os.replace(tmp, path)
    _write_json(record_path(path), record)


def write_file(path, produce, key=None) -> Path:
    """Writes the entry `path`: ``produce(tmp)`` writes the data to a temporary path in the same folder
    (same suffix), which is then committed (:func:`commit_file`). Returns `path`."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = _tmp_name(path)
    try:
        produce(tmp)
        commit_file(tmp, path, key)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def _problem(path: Path, record_file: Path, key):
    """Why the file entry `path` cannot be used (None: it can; "" : it is absent)."""
    if not path.exists():
        return ""
    try:
        record = json.loads(record_file.read_text())
        size, digest = int(record["size"]), str(record["sha256"])
    except FileNotFoundError:
        return "without its checksum record (an interrupted write, or an older msx)"
    except (OSError, ValueError, KeyError, TypeError):
        return "damaged (unreadable checksum record)"
    actual = path.stat().st_size
    if actual != size:
        return f"damaged ({'truncated: ' if actual < size else ''}{actual} bytes, {size} written)"
    if _digest(path) != digest:
        return "damaged (its checksum does not match)"
    if key is not None and record.get("key") != key:
        return "stale (made from other inputs)"
    return None


def valid_file(path, key=None) -> bool:
    """True if the file entry `path` is there and matches its record; says nothing and deletes nothing."""
    path = Path(path)
    return _problem(path, record_path(path), key) is None


def check_file(path, key=None) -> bool:
    """True if the file entry `path` is there and matches its record (and `key`, if given). A present entry
    that does not is reported in one line and deleted; absent ones are simply False."""
    path = Path(path)
    problem = _problem(path, record_path(path), key)
    if problem is None:
        return True
    if problem:
        report(path, problem)
        remove(path)
    return False


def remove(path):
    """Deletes a file entry and its record, or a folder entry."""
    path = Path(path)
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        record_path(path).unlink(missing_ok=True)
        path.unlink(missing_ok=True)


def _files(folder: Path):
    return sorted(p for p in folder.rglob("*") if p.is_file() and p.name != MANIFEST)


def make_folder(path, produce, key=None) -> Path:
    """Builds the folder entry `path`: ``produce(tmp_folder)`` fills a temporary folder beside it, a manifest
    of every file is written into it, and it is renamed into place. If another process made the entry
    meanwhile, its entry is kept. Returns `path`."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp")
    try:
        tmp.mkdir()
        produce(tmp)
        files = {p.relative_to(tmp).as_posix(): {"size": p.stat().st_size, "sha256": _digest(p)}
                 for p in _files(tmp)}
        (tmp / MANIFEST).write_text(json.dumps({"files": files, "key": key}, sort_keys=True))
        try:
            os.rename(tmp, path)  # atomic; fails if `path` exists (made meanwhile)
        except OSError:
            if not path.is_dir():
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return path


def check_folder(path, key=None) -> bool:
    """True if the folder entry `path` is there and every file matches its manifest (none missing, none
    added); a present entry that does not is reported in one line and deleted."""
    path = Path(path)
    if not path.exists():
        return False
    problem = None
    try:
        manifest = json.loads((path / MANIFEST).read_text())
        files = manifest["files"]
    except FileNotFoundError:
        problem = "without its manifest (an interrupted write, or an older msx)"
    except (OSError, ValueError, KeyError, TypeError):
        problem = "damaged (unreadable manifest)"
    else:
        present = {p.relative_to(path).as_posix(): p for p in _files(path)}
        for name, rec in sorted(files.items()):
            p = present.pop(name, None)
            if p is None:
                problem = f"damaged ({name} is missing)"
            elif p.stat().st_size != rec["size"]:
                problem = f"damaged ({name}: {p.stat().st_size} bytes, {rec['size']} written)"
            elif _digest(p) != rec["sha256"]:
                problem = f"damaged ({name}: its checksum does not match)"
            if problem:
                break
        if problem is None and present:
            problem = f"damaged ({sorted(present)[0]} was added)"
        if problem is None and key is not None and manifest.get("key") != key:
            problem = "stale (made from other inputs)"
    if problem is None:
        return True
    report(path, problem)
    remove(path)
    return False


def key_of(*parts) -> str:
    """A short hash of the inputs an entry depends on (bytes, or anything JSON can write)."""
    h = hashlib.sha256()
    for part in parts:
        h.update(part if isinstance(part, bytes) else json.dumps(part, sort_keys=True, default=str).encode())
        h.update(b"\0")
    return h.hexdigest()[:20]


_DIGESTS = {}


def digest_files(*paths) -> str:
    """SHA-256 of files' bytes (once per process and file set): what a cached result computed by that code
    depends on."""
    key = tuple(str(p) for p in paths)
    if key not in _DIGESTS:
        h = hashlib.sha256()
        for p in paths:
            h.update(Path(p).name.encode() + b"\0")
            with open(p, "rb") as f:
                for block in iter(lambda: f.read(1 << 20), b""):
                    h.update(block)
        _DIGESTS[key] = h.hexdigest()
    return _DIGESTS[key]


def core_digest() -> str:
    """The digest of the compiled Rust core (the ``msx._native`` extension): any change of the core's code
    changes it."""
    from . import _native

    return digest_files(_native.__file__)


# ---------------------------------------------------------------- msx cache


def _size(path: Path) -> int:
    if path.is_file() or path.is_symlink():
        return path.lstat().st_size
    return sum(p.lstat().st_size for p in path.rglob("*") if p.is_file() or p.is_symlink())


def _entries(path: Path) -> int:
    return sum(1 for p in path.iterdir() if not p.name.startswith("."))


def _human(n: int) -> str:
    for unit in ("bytes", "KB", "MB", "GB"):
        if n < 1024 or unit == "GB":
            return f"{n} {unit}" if unit == "bytes" else f"{n:.1f} {unit}"
        n /= 1024
    return str(n)


def usage():
    """[(kind, folder, entries, bytes)] for each kind present, then ("other", path, 1, bytes) for anything
    else in the cache folder (an older msx kept its reference renders at the top)."""
    base = root()
    rows = []
    for kind in KINDS:
        f = base / kind
        if f.is_dir():
            rows.append((kind, f, _entries(f), _size(f)))
    if base.is_dir():
        for p in sorted(base.iterdir()):
            if p.name not in KINDS:
                rows.append(("other", p, 1, _size(p)))
    return rows


def describe() -> str:
    base = root()
    state = "" if base.is_dir() else " (not a folder: set MSX_CACHE_DIR to one)" if base.exists() else \
        " (empty: not created yet)"
    lines = [f"msx cache: {base}{state}"]
    rows = usage()
    for kind, f, n, size in rows:
        what = KINDS.get(kind, "not msx's: left alone by --clear" if not _ours(f) else "from an older msx")
        name = f.name + ("/" if f.is_dir() else "")
        lines.append(f"  {name:<14} {n:>4} entr{'y' if n == 1 else 'ies'}  {_human(size):>10}  {what}")
    if rows:
        lines.append(f"  total {_human(sum(r[3] for r in rows))}; `msx cache --clear` deletes it")
    return "\n".join(lines)


def _ours(p: Path) -> bool:
    """Files an older msx left at the top of the cache folder (reference renders, their partial writes)."""
    return p.is_file() and p.name.startswith("reference-") and ".npz" in p.name


def clear():
    """Deletes every kind's folder (and what older versions of msx left at the top); returns
    ([(path, bytes)] deleted, [paths] left alone because msx did not make them)."""
    base = root()
    deleted, kept = [], []
    for kind, f, n, size in usage():
        if kind in KINDS or _ours(f):
            if f.is_dir():
                shutil.rmtree(f)  # an error (a file that cannot be deleted) is the caller's to report
            else:
                f.unlink(missing_ok=True)
            deleted.append((f, n, size))
        else:
            kept.append(f)
    try:
        base.rmdir()  # only if empty
    except OSError:
        pass
    return deleted, kept
