"""NPZ archives (`numpy.savez`), read without pickle and within size limits.

`np.load` would take the last of two members with one name, accept members that are not arrays, and
allocate whatever shape a member's header declares.  Here the archive's members are listed first: a
name twice, or a member that is not `.npy`, is refused; each header is read and its declared size
checked against `files.MAX_ARRAY_BYTES` before its data is; an array of Python objects (which only
pickle could load) is reported, not loaded.
"""

from __future__ import annotations

import io
import zipfile
import zlib
from collections import Counter

import numpy as np

from deint_env.errors import DeintError
from deint_env.formats.files import check_array_size

PICKLED = "the array holds Python objects, which only pickle could load"
_HEADER_READERS = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}


def read_npz(raw: bytes, where: str) -> dict[str, np.ndarray | str]:
    """Every array of an NPZ archive by name (".npy" dropped); an array that would need pickle is
    replaced by `PICKLED`.  Every problem with the archive is one `DeintError` line naming `where`."""
    try:
        with zipfile.ZipFile(io.BytesIO(raw)) as z:
            members = z.infolist()
            twice = [name for name, k in Counter(m.filename for m in members).items() if k > 1]
            if twice:
                raise DeintError(f"{where}: member {twice[0]!r} appears twice in the archive; each array once")
            for m in members:
                if not m.filename.endswith(".npy"):
                    raise DeintError(f"{where}: member {m.filename!r} is not a .npy array; an NPZ archive "
                                     f"holds only .npy members")
            return {m.filename[:-4]: _read_member(z, m, where) for m in members}
    except (zipfile.BadZipFile, zipfile.LargeZipFile, zlib.error, EOFError, OSError, ValueError) as e:
        raise DeintError(f"{where}: is not a readable NPZ archive ({str(e).splitlines()[0] if str(e) else e!r}); "
                         f"is it truncated?") from None


def _read_member(z: zipfile.ZipFile, member: zipfile.ZipInfo, where: str) -> np.ndarray | str:
    name = member.filename[:-4]
    with z.open(member) as f:
        version = np.lib.format.read_magic(f)
        if version not in _HEADER_READERS:
            raise DeintError(f"{where}: array {name!r} is in NPY format version {version}; 1.0 and 2.0 are read")
        shape, _, dtype = _HEADER_READERS[version](f)
    if dtype.hasobject:
        return PICKLED
    check_array_size(shape, dtype.itemsize, f"{where}: array {name!r}")
    with z.open(member) as f:
        return np.lib.format.read_array(f, allow_pickle=False)
