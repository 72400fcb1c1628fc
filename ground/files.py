"""Files the ground tools write for a user: every output is written whole or not at all
(a temporary file in the target's folder renamed into place, so a full disk or a crash
never leaves a truncated file where a good one was), never onto one of the command's own
inputs, only with an extension the writer produces, never over an existing file without
``--force``, and only into a folder that exists (a typo in a path creates no folders).
One rule for every output a user names (:func:`check_output`, ``README.md``, Exit status)."""

import os
import tempfile
from pathlib import Path


def write_atomic(target, data, folders=False):
    """Write ``data`` (bytes or str) to ``target`` through a temporary file renamed into
    place.  ``folders``: create the target's missing folders (the tools' own caches);
    otherwise a missing folder is an error.  Raises ``OSError`` (the target is then
    untouched)."""
    target = Path(target)
    if folders:
        target.parent.mkdir(parents=True, exist_ok=True)
    elif not target.parent.is_dir():
        raise FileNotFoundError(f"{target}: the folder {target.parent} does not exist")
    fd, tmp = tempfile.mkstemp(prefix="." + target.name + ".", suffix=".tmp",
                               dir=target.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data.encode() if isinstance(data, str) else data)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, _mode(target))         # mkstemp's 0600 is not what a user expects
        os.replace(tmp, target)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def _mode(target):
    """The permissions of the file being replaced, else those a new file gets (umask)."""
    try:
        return os.stat(target).st_mode & 0o777
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


def check_output(path, suffixes, inputs=(), what="output", force=False):
    """Raise ``ValueError`` unless ``path`` may be written as ``what``: its extension is one
    of ``suffixes`` (lower case, with the dot; None: any), it is none of ``inputs`` (paths
    the command reads; compared as files, so a link or another spelling of an input is
    refused too), its folder exists, it is not a folder and it does not exist unless
    ``force`` (``--force``).  Commands check every output before their work."""
    path = Path(path)
    if suffixes is not None and path.suffix.lower() not in suffixes:
        raise ValueError(f"{what} {path}: the file must end in {' or '.join(suffixes)}")
    for source in inputs:
        source = Path(source)
        same = path.resolve() == source.resolve()
        if not same and path.exists() and source.exists():
            same = os.path.samefile(path, source)
        if same:
            raise ValueError(f"{what} {path} is an input of this command; it is not "
                             f"overwritten")
    folder = path.parent
    if not folder.is_dir():
        raise ValueError(f"{what} {path}: the folder {folder} does not exist")
    if path.is_dir():
        raise ValueError(f"{what} {path} is a folder")
    if path.exists() and not force:
        raise ValueError(f"{what} {path} exists; give --force to replace it")
