"""The install space as the COMMAND check sees it (runtime/installview.py): names, modes, links
and every script as they are, compiled files empty, so that an edit of compiled code only
leaves the view, and with it the check's cache key, unchanged."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from docker_ros.in_image.runtime.installview import main, make_view


def install_space(root: Path, program: bytes) -> Path:
    install = root / "install"
    lib = install / "pkg" / "lib" / "pkg"
    lib.mkdir(parents=True)
    (install / "setup.bash").write_text("source local_setup.bash\n")
    (install / "_local_setup_util_sh.py").write_text("print('x')\n")
    node = lib / "node"
    node.write_bytes(program)
    node.chmod(0o755)
    (install / "pkg" / "lib" / "libpkg.a").write_bytes(b"!<arch>\n" + os.urandom(64))
    script = lib / "tool.py"
    script.write_text("#!/usr/bin/env python3\n")
    script.chmod(0o750)
    (install / "pkg" / "lib" / "libpkg.so").symlink_to("libpkg.so.1")
    (install / "pkg" / "share").mkdir()
    (install / "pkg" / "share" / "pkg").symlink_to("../lib/pkg", target_is_directory=True)
    locked = install / "pkg" / "private"
    locked.mkdir()
    (locked / "data.txt").write_text("kept\n")
    locked.chmod(0o500)
    return install


def listing(root: Path) -> dict:
    """Each entry below root: (mode, link target or content)."""
    found = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for name in dirnames + filenames:
            path = Path(dirpath) / name
            st = path.lstat()
            body = os.readlink(path) if path.is_symlink() else (
                path.read_bytes() if path.is_file() else None)
            found[str(path.relative_to(root))] = (oct(st.st_mode), body)
    return found


def test_view_keeps_names_modes_links_and_scripts_and_empties_compiled_files(tmp_path):
    true = shutil.which("true")
    assert true, "no `true` program to stand for a compiled file"
    install = install_space(tmp_path, Path(true).read_bytes())
    assert main([str(install), str(tmp_path / "view")]) == 0
    view, real = listing(tmp_path / "view"), listing(install)
    assert view.keys() == real.keys()
    assert {k: mode for k, (mode, _) in view.items()} == {k: m for k, (m, _) in real.items()}
    emptied = sorted(k for k in real if view[k][1] != real[k][1])
    assert emptied == ["pkg/lib/libpkg.a", "pkg/lib/pkg/node"]
    assert view["pkg/lib/pkg/node"][1] == b"" and view["pkg/lib/libpkg.a"][1] == b""
    assert view["pkg/share/pkg"][1] == "../lib/pkg"  # a link, not followed
    assert view["pkg/private/data.txt"][1] == b"kept\n"  # inside a read-only folder


def test_view_is_the_same_after_a_change_of_compiled_code_only(tmp_path):
    true, false = shutil.which("true"), shutil.which("false")
    assert true and false
    first = install_space(tmp_path / "a", Path(true).read_bytes())
    second = install_space(tmp_path / "b", Path(false).read_bytes())
    make_view(first, tmp_path / "view-a")
    make_view(second, tmp_path / "view-b")
    assert listing(tmp_path / "view-a") == listing(tmp_path / "view-b")
    # a script's change is the check's business: the view changes with it
    (second / "setup.bash").write_text("source other.bash\n")
    make_view(second, tmp_path / "view-c")
    assert listing(tmp_path / "view-c") != listing(tmp_path / "view-a")


def test_a_view_that_exists_is_one_message(tmp_path, capsys):
    (tmp_path / "install").mkdir()
    (tmp_path / "view").mkdir()
    assert main([str(tmp_path / "install"), str(tmp_path / "view")]) == 1
    assert capsys.readouterr().err.startswith("docker-ros colcon: ")
