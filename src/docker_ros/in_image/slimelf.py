"""ELF files as the dynamic loader reads them, for `docker-ros slim`'s keep set: an object's
interpreter, DT_NEEDED libraries and search paths (DT_RPATH, DT_RUNPATH, $ORIGIN), and where
ld.so would find each library (ld.so.conf with its includes, the default folders). The loader's
rules change together, apart from the tracing in slimtrace.py beside it.

Standard library only, Python 3.8: the host copies it into the run image's container beside
slimtrace.py, which imports it from there (no docker_ros package is in the run image)."""

import glob
import mmap
import os
import struct
from typing import List, Optional, Set, Tuple

# ELF class (1: 32-bit, 2: 64-bit), machine, interpreter, DT_NEEDED, DT_RPATH, DT_RUNPATH
Elf = Tuple[int, int, Optional[str], List[str], List[str], List[str]]

DT_NULL, DT_NEEDED, DT_STRTAB, DT_RPATH, DT_RUNPATH = 0, 1, 5, 15, 29
PT_LOAD, PT_DYNAMIC, PT_INTERP = 1, 2, 3
DEFAULT_LIB_DIRS = ("/lib", "/usr/lib", "/lib64", "/usr/lib64")


def parse_elf(data: bytes) -> Optional[Elf]:
    """(class 1|2, machine, interpreter, needed, rpath, runpath) of an ELF file's bytes, or None
    for anything that is not a dynamically linked ELF file."""
    if len(data) < 64 or data[:4] != b"\x7fELF" or data[4] not in (1, 2) or data[5] not in (1, 2):
        return None
    wide = data[4] == 2
    end = "<" if data[5] == 1 else ">"
    machine = struct.unpack_from(end + "H", data, 18)[0]
    if wide:
        phoff, = struct.unpack_from(end + "Q", data, 32)
        phentsize, phnum = struct.unpack_from(end + "HH", data, 54)
        ph = struct.Struct(end + "IIQQQQQQ")  # type flags offset vaddr paddr filesz memsz align
    else:
        phoff, = struct.unpack_from(end + "I", data, 28)
        phentsize, phnum = struct.unpack_from(end + "HH", data, 42)
        ph = struct.Struct(end + "IIIIIIII")  # type offset vaddr paddr filesz memsz flags align
    loads: List[Tuple[int, int, int]] = []
    dynamic: Optional[Tuple[int, int]] = None
    interp: Optional[str] = None
    for index in range(phnum):
        at = phoff + index * phentsize
        if at + ph.size > len(data):
            return None
        fields = ph.unpack_from(data, at)
        if wide:
            kind, offset, vaddr, filesz = fields[0], fields[2], fields[3], fields[5]
        else:
            kind, offset, vaddr, filesz = fields[0], fields[1], fields[2], fields[4]
        if kind == PT_LOAD:
            loads.append((vaddr, offset, filesz))
        elif kind == PT_DYNAMIC:
            dynamic = (offset, filesz)
        elif kind == PT_INTERP:
            interp = data[offset:offset + filesz].split(b"\0")[0].decode(errors="replace")
    if dynamic is None:
        return (data[4], machine, interp, [], [], []) if interp else None
    entry = struct.Struct(end + ("qQ" if wide else "iI"))
    tags: List[Tuple[int, int]] = []
    for at in range(dynamic[0], dynamic[0] + dynamic[1], entry.size):
        if at + entry.size > len(data):
            break
        tag, value = entry.unpack_from(data, at)
        if tag == DT_NULL:
            break
        tags.append((tag, value))
    strtab = next((value for tag, value in tags if tag == DT_STRTAB), None)
    if strtab is None:
        return None
    base = next((off + strtab - vaddr for vaddr, off, size in loads
                 if vaddr <= strtab < vaddr + size), None)
    if base is None:
        return None

    def string(offset: int) -> str:
        end = data.find(b"\0", base + offset)  # bytes and mmap both have find
        return data[base + offset:end if end >= 0 else len(data)].decode(errors="replace")

    def strings(wanted: int) -> List[str]:
        return [string(value) for tag, value in tags if tag == wanted]

    rpath = [d for s in strings(DT_RPATH) for d in s.split(":") if d]
    runpath = [d for s in strings(DT_RUNPATH) for d in s.split(":") if d]
    return (data[4], machine, interp, strings(DT_NEEDED), rpath, runpath)


def read_elf(path: str) -> Optional[Elf]:
    """parse_elf of a file, mapped rather than read: only the pages holding the headers and the
    dynamic section are loaded, not a whole library."""
    try:
        with open(path, "rb") as handle:
            if handle.read(4) != b"\x7fELF":
                return None
            with mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ) as data:
                return parse_elf(data)  # type: ignore[arg-type]
    except (OSError, ValueError):
        return None


def ld_so_conf_dirs(path: str = "/etc/ld.so.conf", seen: Optional[Set[str]] = None) -> List[str]:
    """The library folders of ld.so.conf, following `include` globs."""
    seen = set() if seen is None else seen
    if path in seen or not os.path.isfile(path):
        return []
    seen.add(path)
    folders: List[str] = []
    with open(path, errors="replace") as handle:
        for line in handle:
            line = line.split("#", 1)[0].strip()
            if line.startswith("include "):
                pattern = line.split(None, 1)[1]
                if not pattern.startswith("/"):
                    pattern = os.path.join(os.path.dirname(path), pattern)
                for included in sorted(glob.glob(pattern)):
                    folders += ld_so_conf_dirs(included, seen)
            elif line:
                folders.append(line)
    return folders


def expand_origin(folder: str, origin: str) -> str:
    return folder.replace("$ORIGIN", origin).replace("${ORIGIN}", origin) \
        .replace("$LIB", "lib").replace("${LIB}", "lib")


def find_library(name: str, elf: Elf, path: str, library_path: List[str],
                 system_dirs: List[str]) -> Optional[str]:
    """Where ld.so would find DT_NEEDED `name` of the object at path (class must match)."""
    if "/" in name:
        return name if os.path.exists(name) else None
    origin = os.path.dirname(os.path.realpath(path))
    _, _, _, _, rpath, runpath = elf
    folders = ([] if runpath else rpath) + library_path + runpath + system_dirs
    for folder in folders:
        candidate = os.path.join(expand_origin(folder, origin), name)
        if os.path.exists(candidate):
            found = read_elf(candidate)
            if found is None or (found[0], found[1]) == (elf[0], elf[1]):
                return candidate
    return None
