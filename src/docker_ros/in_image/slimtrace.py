"""In-image half of `docker-ros slim`: trace what a command opens, then compute the keep set.

Runs inside a container of the run image (standard library only, Python 3.8), bind-mounted by
the host side (docker_ros.host.slim) together with an exchange folder. The run image has no
docker_ros package to import from: the host copies this file and slimelf.py (the loader's rules
for ELF files) into the container's exchange folder, where this one imports the other.

    python3 slimtrace.py --out DIR -- ENTRYPOINT... CMD...

1. marks the container's root mount with fanotify (needs CAP_SYS_ADMIN) and starts the command;
2. records every path opened or executed on that mount, by the command and by anything the host
   runs with `docker exec` meanwhile, until it gets SIGTERM (`docker kill -s TERM`); when the
   command exits it says so on stderr (EXITED) and stays up for the execs; when the set of
   traced files has not grown for spec["settle_seconds"], it says that too (SETTLED), so that
   the host stops watching a command that has started all it needs; on SIGUSR1 it writes the
   keep set of what it traced so far (below) and says so (SNAPSHOT), tracing on: the host
   makes the slim image from it while the command goes on, and adds what it opens later;
3. stops the command and writes DIR/keep.txt: the traced files plus the include paths and
   essentials of DIR/spec.json, closed over ELF DT_NEEDED (ld.so search rules), Python sources
   beside their bytecode, symlinks leading to kept files, hard links, parent directories;
   minus the exclude patterns. DIR/done marks the end (DIR/error on failure).
"""

import ctypes
import json
import os
import re
import select
import signal
import struct
import subprocess
import sys
import time
from typing import Any, Callable, Dict, Iterable, Iterator, List, Optional, Set, Tuple

try:  # (in the run image it is a lone file beside this one; on the host, in the package)
    from docker_ros.in_image.slimelf import (
        DEFAULT_LIB_DIRS,
        find_library,
        ld_so_conf_dirs,
        read_elf,
    )
except ImportError:
    from slimelf import (  # type: ignore[no-redef]
        DEFAULT_LIB_DIRS,
        find_library,
        ld_so_conf_dirs,
        read_elf,
    )

FAN_CLOEXEC, FAN_NONBLOCK, FAN_CLASS_NOTIF, FAN_UNLIMITED_QUEUE = 0x1, 0x2, 0x0, 0x10
FAN_MARK_ADD, FAN_MARK_MOUNT = 0x1, 0x10
FAN_OPEN, FAN_OPEN_EXEC, FAN_ONDIR, FAN_Q_OVERFLOW = 0x20, 0x1000, 0x40000000, 0x4000
O_LARGEFILE = 0o100000
AT_FDCWD = -100
EVENT = struct.Struct("IBBHQii")
# Never walked: kernel file systems and our own exchange folder.
SKIP_DIRS = ("/proc", "/sys", "/dev", "/docker-ros-slim")
EXITED = "command exited with status "
SETTLED = "traced files settled after "
SNAPSHOT = "keep set written, tracing on: "


def log(message: str) -> None:
    sys.stderr.write(f"docker-ros slimtrace: {message}\n")
    sys.stderr.flush()


# --------------------------------------------------------------------------------- tracing
class Fanotify:
    """Open/exec events of one mount, as paths."""

    def __init__(self, mount: str = "/") -> None:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.fanotify_mark.argtypes = [ctypes.c_int, ctypes.c_uint, ctypes.c_uint64,
                                       ctypes.c_int, ctypes.c_char_p]
        flags = FAN_CLOEXEC | FAN_NONBLOCK | FAN_CLASS_NOTIF | FAN_UNLIMITED_QUEUE
        self.fd = libc.fanotify_init(flags, os.O_RDONLY | O_LARGEFILE | os.O_CLOEXEC)
        if self.fd < 0:
            raise OSError(ctypes.get_errno(), "fanotify_init failed (the trace container needs "
                          "--cap-add SYS_ADMIN): " + os.strerror(ctypes.get_errno()))
        mask = FAN_OPEN | FAN_OPEN_EXEC | FAN_ONDIR
        if libc.fanotify_mark(self.fd, FAN_MARK_ADD | FAN_MARK_MOUNT, mask, AT_FDCWD,
                              mount.encode()) != 0:
            raise OSError(ctypes.get_errno(), "fanotify_mark failed: "
                          + os.strerror(ctypes.get_errno()))
        self.paths: Set[str] = set()
        self.pids: Set[int] = set()
        self.library_path: List[str] = []
        self.overflow = False
        self.own = os.getpid()

    def read(self, timeout: float) -> None:
        ready, _, _ = select.select([self.fd], [], [], timeout)
        if not ready:
            return
        try:
            data = os.read(self.fd, 256 * 1024)
        except BlockingIOError:
            return
        offset = 0
        while offset + EVENT.size <= len(data):
            length, _, _, _, mask, fd, pid = EVENT.unpack_from(data, offset)
            offset += length
            if mask & FAN_Q_OVERFLOW:
                self.overflow = True
            if fd < 0:
                continue
            if pid == self.own:  # the tracer itself, making a keep set while tracing on
                os.close(fd)
                continue
            try:
                self.paths.add(os.readlink(f"/proc/self/fd/{fd}"))
            except OSError:
                pass
            finally:
                os.close(fd)
            if pid not in self.pids:
                self.pids.add(pid)
                self.note_environment(pid)

    def note_environment(self, pid: int) -> None:
        """LD_LIBRARY_PATH of the traced processes (set by sourced setup files) for ld.so."""
        try:
            with open(f"/proc/{pid}/environ", "rb") as handle:
                entries = handle.read().split(b"\0")
        except OSError:
            return
        for entry in entries:
            if entry.startswith(b"LD_LIBRARY_PATH="):
                for folder in entry[16:].decode(errors="replace").split(":"):
                    if folder and folder not in self.library_path:
                        self.library_path.append(folder)

    def close(self) -> None:
        os.close(self.fd)


def reap(child: subprocess.Popen, status: Optional[int]) -> Optional[int]:
    """Reap every exited process (we are PID 1); note the command's exit status."""
    while True:
        try:
            pid, code = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return status
        if pid == 0:
            return status
        if pid == child.pid and status is None:
            status = (os.waitstatus_to_exitcode(code)  # novermin (3.9+, guarded by hasattr)
                      if hasattr(os, "waitstatus_to_exitcode")
                      else (code >> 8 if code & 0x7F == 0 else -(code & 0x7F)))
            if status < 0:  # as a shell reports a signal death
                status = 128 - status


def trace(command: List[str], max_seconds: float, settle_seconds: float = 0.0,
          snapshot: Callable[[Set[str], List[str], bool], None] = lambda *_: None,
          ) -> Tuple[Set[str], List[str], bool]:
    """Trace until SIGTERM (or max_seconds); return (paths, library_path, overflow). Say once
    (SETTLED) when no new file was opened for settle_seconds (0: never); call snapshot with
    what was traced so far on each SIGUSR1."""
    stop: List[bool] = []
    asked: List[bool] = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(True))
    signal.signal(signal.SIGUSR1, lambda *_: asked.append(True))
    notify = Fanotify("/")
    child = subprocess.Popen(command, start_new_session=True)
    status = None
    began = time.monotonic()
    deadline = began + max_seconds
    grown, count, settled = began, 0, False
    while not stop and time.monotonic() < deadline:
        notify.read(0.2)
        if asked:
            asked.clear()
            snapshot(set(notify.paths), list(notify.library_path), notify.overflow)
        now = time.monotonic()
        if len(notify.paths) != count:
            grown, count = now, len(notify.paths)
        elif settle_seconds and not settled and status is None and now - grown >= settle_seconds:
            settled = True
            log(f"{SETTLED}{grown - began:.1f} s ({count} files)")
        if status is None:
            status = reap(child, status)
            if status is not None:
                log(EXITED + str(status))
        else:
            reap(child, status)
    if status is None:
        stop_command(child, notify)
    notify.read(0)
    notify.close()
    return notify.paths, notify.library_path, notify.overflow


def stop_command(child: subprocess.Popen, notify: Fanotify) -> None:
    """SIGTERM to the command's process group, SIGKILL after 10 s; trace its shutdown too."""
    for sig, wait in ((signal.SIGTERM, 10.0), (signal.SIGKILL, 5.0)):
        try:
            os.killpg(child.pid, sig)
        except OSError:
            return
        deadline = time.monotonic() + wait
        while time.monotonic() < deadline:
            notify.read(0.1)
            if reap(child, None) is not None or child.returncode is not None:
                return
            try:
                os.kill(child.pid, 0)
            except OSError:
                return


# ----------------------------------------------------------------------------- keep set
def glob_source(pattern: str) -> str:
    """Glob as in docker-slim's --exclude-pattern, as regex source: `**` crosses `/`, `*` and
    `?` do not."""
    out, index = [], 0
    while index < len(pattern):
        if pattern.startswith("**", index):
            out.append(".*")
            index += 2
        elif pattern[index] == "*":
            out.append("[^/]*")
            index += 1
        elif pattern[index] == "?":
            out.append("[^/]")
            index += 1
        else:
            out.append(re.escape(pattern[index]))
            index += 1
    return "".join(out)


def globs_regex(patterns: List[str]) -> "Optional[re.Pattern[str]]":
    """One regex for paths that match one of the globs or lie below a path that does (one
    match per path: the keep set tests every file of the image against the include paths)."""
    if not patterns:
        return None
    body = "|".join(glob_source(p.rstrip("/") or "/") for p in patterns)
    return re.compile(f"(?:{body})(?:/.*)?\\Z", re.DOTALL)


def matches_any(path: str, regex: "Optional[re.Pattern[str]]") -> bool:
    """True if the path or one of its parent folders matches (regex: globs_regex)."""
    return regex is not None and path != "/" and regex.match(path) is not None


def link_chain(path: str) -> List[str]:
    """The symlinks met while resolving path (any component) and the real path at the end."""
    out: List[str] = []
    pending, seen = [os.path.normpath(path)], set()  # type: Tuple[List[str], Set[str]]
    while pending:
        current = pending.pop()
        if current in seen or len(seen) > 64:
            continue
        seen.add(current)
        parts = current.strip("/").split("/")
        resolved = "/"
        for index, part in enumerate(parts):
            step = os.path.join(resolved, part)
            if os.path.islink(step):
                out.append(step)
                target = os.path.join(resolved, os.readlink(step))
                pending.append(os.path.normpath(os.path.join(target, *parts[index + 1:])))
                break
            resolved = step
        else:
            out.append(current)
    return out


def canonical(path: str) -> str:
    """path with its folder resolved (the name itself may be a symlink)."""
    folder, name = os.path.split(path)
    return os.path.join(os.path.realpath(folder), name)


def which(name: str, path_env: str) -> Optional[str]:
    if "/" in name:
        return name if os.path.exists(name) else None
    for folder in path_env.split(":"):
        candidate = os.path.join(folder or ".", name)
        if os.path.isfile(candidate) and os.access(candidate, os.X_OK):
            return candidate
    return None


def python_companions(path: str) -> List[str]:
    """A module's source beside its bytecode and back: imports need the `.py` to find
    `__pycache__/x.*.pyc`, tracebacks read it; the bytecode spares recompiling."""
    folder, name = os.path.split(path)
    if os.path.basename(folder) == "__pycache__" and name.endswith(".pyc"):
        return [os.path.join(os.path.dirname(folder), name.split(".", 1)[0] + ".py")]
    if name.endswith(".py"):
        cache = os.path.join(folder, "__pycache__")
        try:
            return [os.path.join(cache, n) for n in os.listdir(cache)
                    if n.startswith(name[:-3] + ".") and n.endswith(".pyc")]
        except OSError:
            return []
    return []


Entry = Tuple[str, str, int]  # path, kind ("dir", "link" or "file"), inode number


def walk(root: str, skip: Set[str]) -> Iterator[Entry]:
    """Every path below root (not following symlinks), pruning the skipped folders; the kind
    and inode come from the directory listing (no stat call per file)."""
    pending = [root]
    while pending:
        try:
            entries = list(os.scandir(pending.pop()))
        except OSError:
            continue
        for entry in entries:
            if entry.path in skip:
                continue
            try:
                kind = ("link" if entry.is_symlink() else
                        "dir" if entry.is_dir(follow_symlinks=False) else "file")
                yield entry.path, kind, entry.inode()
            except OSError:
                continue
            if kind == "dir":
                pending.append(entry.path)


def mount_points() -> Set[str]:
    try:
        with open("/proc/self/mountinfo") as handle:
            return {line.split()[4] for line in handle} - {"/"}
    except OSError:
        return set()


def keep_set(spec: Dict[str, Any], traced: Set[str], library_path: List[str]) -> Set[str]:
    """Absolute paths to keep (files, symlinks, folders); see the module docstring."""
    skip = set(SKIP_DIRS) | {m for m in mount_points() if os.path.isdir(m)}
    includes = globs_regex([q for p in spec["include"] for q in {p, canonical(p)}])
    excludes = globs_regex(spec["exclude"])
    roots = set(p for p in traced if not any(p == s or p.startswith(s + "/") for s in skip))
    everything = list(walk("/", skip))
    roots.update(p for p, _, _ in everything if matches_any(p, includes))
    path_env = spec.get("path", "/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin")
    for exe in spec["executables"]:
        found = which(exe, path_env)
        if found:
            roots.add(found)
    system_dirs = ld_so_conf_dirs() + list(DEFAULT_LIB_DIRS)
    keep = set()
    pending = sorted(roots)
    while pending:
        path = pending.pop()
        if path in keep or matches_any(path, excludes) \
                or matches_any(canonical(path), excludes):
            continue
        keep.add(path)
        pending += [p for p in link_chain(path) if p not in keep]
        if not os.path.isfile(path) or os.path.islink(path):
            continue
        pending += python_companions(path) + interpreter(path)
        elf = read_elf(path)
        if elf is None:
            continue
        if elf[2]:
            pending.append(elf[2])
        for name in elf[3]:
            found = find_library(name, elf, path, library_path, system_dirs)
            if found:
                pending.append(found)
    keep |= ancestors(keep)
    kept_real = {os.path.realpath(p) for p in keep}
    inodes = set()
    for path in keep:
        try:
            info = os.lstat(path)
        except OSError:
            continue
        if info.st_nlink > 1 and not os.path.isdir(path):
            inodes.add((info.st_dev, info.st_ino))
    numbers = {number for _, number in inodes}
    for path, kind, number in everything:
        if path in keep or matches_any(path, excludes):
            continue
        if kind == "link":
            if os.path.realpath(path) in kept_real:
                keep.add(path)  # e.g. libfoo.so.1 -> libfoo.so.1.2, /usr/bin/python3 -> python3.11
        elif kind == "dir":
            if path.count("/") <= 2:
                keep.add(path)  # the folder skeleton: /var/tmp, /etc/skel, /usr/share...
        elif number in numbers and same_file(path, inodes):
            keep.add(path)  # the other names of a kept hard-linked file
    keep |= ancestors(keep)
    return without_aliases(p for p in keep if p != "/" and os.path.lexists(p))


def without_aliases(paths: Iterable[str]) -> Set[str]:
    """paths without the names reached through a symlinked folder (/lib/x86_64-linux-gnu/libc.so.6
    when /lib -> usr/lib): an image's files have one name each, and link_chain kept the real one
    and the symlink."""
    return {p for p in paths if canonical(p) == p}


def same_file(path: str, inodes: Set[Tuple[int, int]]) -> bool:
    try:
        info = os.lstat(path)
    except OSError:
        return False
    return (info.st_dev, info.st_ino) in inodes


def ancestors(paths: Set[str]) -> Set[str]:
    out: Set[str] = set()
    for path in paths:
        parent = os.path.dirname(path)
        while parent != "/" and parent not in out:
            out.add(parent)
            parent = os.path.dirname(parent)
    return out


def interpreter(path: str) -> List[str]:
    """The `#!` interpreter of a script (the kernel opens it for exec; its path may go through
    symlinks such as /bin -> usr/bin that the trace does not see)."""
    try:
        with open(path, "rb") as handle:
            head = handle.read(256)
    except OSError:
        return []
    if not head.startswith(b"#!"):
        return []
    words = head[2:].split(b"\n", 1)[0].split()
    return [words[0].decode(errors="replace")] if words else []


def path_matches(pattern: str) -> bool:
    """Whether a path of this image matches an --include-path/--preserve-path (a glob: as the
    keep set matches it, searched below its folder without a glob character)."""
    if not any(c in pattern for c in "*?"):
        return os.path.lexists(pattern)
    top = pattern[:min(pattern.find(c) for c in "*?" if c in pattern)].rpartition("/")[0]
    regex = globs_regex([pattern])
    return any(matches_any(p, regex) for p, _, _ in walk(top or "/", set(SKIP_DIRS)))


def missing_requests(spec: Dict[str, Any]) -> List[str]:
    """The --include-exe names not on PATH, --include-bin files that do not exist and
    --include-path/--preserve-path paths nothing matches, as "OPTION VALUE" (those options
    would keep nothing)."""
    path_env = spec.get("path", "/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin")
    missing = []
    for option, value in spec.get("requested", []):
        found = (which(value, path_env) if option == "--include-exe"
                 else os.path.lexists(value) if option == "--include-bin"
                 else path_matches(value))
        if not found:
            missing.append(f"{option} {value}")
    return missing


def write(path: str, text: str) -> None:
    with open(path + ".tmp", "w") as handle:
        handle.write(text)
    os.rename(path + ".tmp", path)


def main(argv: List[str]) -> int:
    if len(argv) < 3 or argv[0] != "--out" or argv[2] != "--":
        log("usage: slimtrace.py --out DIR -- COMMAND...")
        return 2
    out, command = argv[1], argv[3:]
    try:
        with open(out + "/spec.json") as handle:
            spec = json.load(handle)
        began = time.monotonic()
        missing: List[List[str]] = []  # (the image's files do not change: looked up once)

        def results(paths: Set[str], library_path: List[str], overflow: bool) -> None:
            traced_seconds = time.monotonic() - began
            keep = keep_set(spec, paths, library_path)
            keep_seconds = time.monotonic() - began - traced_seconds
            if not missing:
                missing.append(missing_requests(spec))
            write(out + "/keep.txt", "".join(p + "\n" for p in sorted(keep)))
            write(out + "/done", json.dumps({
                "traced": len(paths), "kept": len(keep), "overflow": overflow,
                "library_path": library_path, "trace_seconds": round(traced_seconds, 1),
                "keep_seconds": round(keep_seconds, 1),
                "missing": missing[0],
            }))

        def snapshot(paths: Set[str], library_path: List[str], overflow: bool) -> None:
            results(paths, library_path, overflow)
            log(f"{SNAPSHOT}{len(paths)} files")

        results(*trace(command, spec["max_seconds"], spec.get("settle_seconds", 0.0),
                       snapshot))
    except Exception as exc:  # reported to the host, which names it in one line
        write(out + "/error", f"{type(exc).__name__}: {exc}\n")
        log(f"{type(exc).__name__}: {exc}")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
