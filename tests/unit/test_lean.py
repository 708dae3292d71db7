"""The decisions of the lean run image (ENABLE_LEAN_RUN_IMAGE): which packages stay, which
files are whose, what ldd and a Python source say. The image build itself is tested in
tests/docker/test_lean.py."""

import json
from pathlib import Path

from docker_ros.core.loading import load_settings
from docker_ros.host.buildplan import definition, run_resolution
from docker_ros.in_image.runtime.lean import (
    canonical,
    dpkg_index,
    imported_modules,
    install_files,
    is_dev_package,
    lean_packages,
    lean_resolution,
    local_names,
    optional_modules,
    owners,
    parse_ldd,
    providers,
)
from docker_ros.in_image.runtime.workspace import Workspace

LDD = """\
\tlinux-vdso.so.1 (0x00007ffd5b3f6000)
\tliblean_greet.so => /docker-ros/ws/install/lean_yaml/lib/liblean_greet.so (0x00007f1)
\tlibyaml-cpp.so.0.7 => /lib/x86_64-linux-gnu/libyaml-cpp.so.0.7 (0x00007f2)
\tlibgone.so.3 => not found
\t/lib64/ld-linux-x86-64.so.2 (0x00007f3)
"""


def test_dev_packages_are_dropped_and_needed_ones_added() -> None:
    declared = ["libroscpp-dev", "python3-rospy", "libyaml-cpp-dev", "ros-std-msgs",
                "libfoo-dev:amd64"]
    assert lean_packages(declared, {"libroscpp4d", "libyaml-cpp0.7", "python3-rospy"}) == [
        "libroscpp4d", "libyaml-cpp0.7", "python3-rospy", "ros-std-msgs"]
    assert is_dev_package("libc6-dev:arm64") and not is_dev_package("python3-devtools")


def test_a_library_only_a_dev_package_ships_is_kept() -> None:
    assert lean_packages(["libgtest-dev"], {"libgtest-dev"}) == ["libgtest-dev"]


def test_parse_ldd_finds_paths_and_missing_libraries() -> None:
    paths, missing = parse_ldd(LDD)
    assert paths == ["/docker-ros/ws/install/lean_yaml/lib/liblean_greet.so",
                     "/lib/x86_64-linux-gnu/libyaml-cpp.so.0.7", "/lib64/ld-linux-x86-64.so.2"]
    assert missing == ["libgone.so.3"]


def test_canonical_spelling_on_a_merged_usr() -> None:
    assert canonical("/lib/x86_64-linux-gnu/libc.so.6") == "/usr/lib/x86_64-linux-gnu/libc.so.6"
    assert canonical("/usr/lib/x86_64-linux-gnu//libc.so.6") == \
        "/usr/lib/x86_64-linux-gnu/libc.so.6"
    assert canonical("/bin/bash") == "/usr/bin/bash"
    assert canonical("/library/x") == "/library/x"


def test_owners_by_path_or_through_a_symlink(tmp_path: Path) -> None:
    info = tmp_path / "info"
    info.mkdir()
    real = tmp_path / "libyaml-cpp.so.0.7.0"
    real.write_text("")
    link = tmp_path / "libyaml-cpp.so.0.7"
    link.symlink_to(real.name)
    (info / "libyaml-cpp0.7:amd64.list").write_text(f"/.\n{real}\n")
    (info / "libc6.list").write_text("/.\n/lib/x86_64-linux-gnu/libc.so.6\n")
    index = dpkg_index(info)
    assert owners(str(link), index) == {"libyaml-cpp0.7"}
    assert owners("/usr/lib/x86_64-linux-gnu/libc.so.6", index) == {"libc6"}
    found, unowned = providers({str(link): {"bin/node"}, "/usr/local/lib/x.so": {"bin/node"}},
                               index)
    assert found == {"libyaml-cpp0.7": {str(link)}}
    assert unowned == ["/usr/local/lib/x.so"]


def test_imported_modules_are_top_level_absolute_names() -> None:
    source = ("import os.path, yaml as y\nfrom std_msgs.msg import String\n"
              "from . import sibling\nfrom .pkg import x\n"
              "def f():\n    try:\n        import psutil\n    except ImportError:\n        pass\n")
    assert imported_modules(source) == {"os", "yaml", "std_msgs", "psutil"}


def test_install_files_sorts_elf_and_python(tmp_path: Path) -> None:
    (tmp_path / "lib" / "pkg" / "__pycache__").mkdir(parents=True)
    (tmp_path / "lib" / "pkg" / "node").write_bytes(b"\x7fELF\x02\x01")
    (tmp_path / "lib" / "pkg" / "listener").write_text("#!/usr/bin/env python3\nimport rospy\n")
    (tmp_path / "lib" / "pkg" / "mod.py").write_text("import yaml\n")
    (tmp_path / "lib" / "pkg" / "run.sh").write_text("#!/bin/sh\n")
    (tmp_path / "lib" / "pkg" / "__pycache__" / "mod.cpython-311.pyc").write_bytes(b"\x7fELF")
    (tmp_path / "lib" / "pkg" / "link").symlink_to("node")
    elf, python = install_files(tmp_path)
    assert elf == [tmp_path / "lib" / "pkg" / "node"]
    assert python == [tmp_path / "lib" / "pkg" / "listener", tmp_path / "lib" / "pkg" / "mod.py"]
    assert {"mod", "node", "listener"} <= local_names(tmp_path / "lib" / "pkg" / "listener")


def test_the_run_image_is_resolved_by_the_lean_stage_only_when_enabled(tmp_path: Path) -> None:
    for value, stage in (("true", "lean-resolution"), ("false", "resolve")):
        settings = load_settings(environ={"ENABLE_LEAN_RUN_IMAGE": value, "BASE_IMAGE": "b",
                                          "COMMAND": "c"}, project_dir=tmp_path)
        assert run_resolution(settings) == stage
        spec = definition(settings, target="run", platform="amd64", tools_image="t", tag="x",
                          secrets={})
        assert spec["args"]["DOCKER_ROS_RUN_RESOLUTION"] == stage


def test_the_resolution_changes_only_with_the_packages(tmp_path: Path) -> None:
    """lean_resolution on a real workspace (this machine's dpkg database and python3): the copy
    holds the resolution with the exec set replaced, the report lies beside it (the run image's
    dependency layer is keyed by the copy's content), and a new file needing nothing new leaves
    the copy as it was."""
    ws = Workspace(tmp_path / "ws")
    script = ws.install / "pkg" / "lib" / "pkg" / "node.py"
    script.parent.mkdir(parents=True)
    script.write_text("import json\nimport no_such_module_anywhere\n")
    resolved = tmp_path / "resolved"
    resolved.mkdir()
    (resolved / "rosdep.json").write_text(json.dumps(
        {"all": {"apt": ["libfoo-dev"], "pip": []},
         "exec": {"apt": ["libfoo-dev", "python3-foo"], "pip": ["bar"]}}))
    (resolved / "debs.json").write_text('{"packages": ["procps"]}')
    settings = load_settings(environ={"BASE_IMAGE": "b"}, project_dir=tmp_path)
    report = lean_resolution(ws, settings, resolved, tmp_path / "lean")
    assert sorted(p.name for p in (tmp_path / "lean").iterdir()) == ["debs.json", "rosdep.json"]
    plan = json.loads((tmp_path / "lean" / "rosdep.json").read_text())
    assert plan["exec"]["pip"] == ["bar"] and plan["all"]["apt"] == ["libfoo-dev"]
    assert "libfoo-dev" not in plan["exec"]["apt"] and "python3-foo" in plan["exec"]["apt"]
    assert report["dropped"] == ["libfoo-dev"]
    assert any(m.startswith("no_such_module_anywhere") for m in report["not_found"])  # type: ignore
    assert json.loads((tmp_path / "lean.json").read_text()) == report
    before = (tmp_path / "lean" / "rosdep.json").read_text()
    (script.parent / "other.py").write_text("import json\n")
    lean_resolution(ws, settings, resolved, tmp_path / "lean")
    assert (tmp_path / "lean" / "rosdep.json").read_text() == before


# setuptools' console-script wrapper, as colcon installs every ament_python entry point
CONSOLE_SCRIPT = """import re
import sys
try:
    from importlib.metadata import distribution
except ImportError:
    try:
        from importlib_metadata import distribution
    except ImportError:
        from pkg_resources import load_entry_point
"""


def test_imports_in_a_try_catching_import_error_are_optional() -> None:
    assert optional_modules(CONSOLE_SCRIPT) == {"importlib", "importlib_metadata",
                                                "pkg_resources"}
    assert optional_modules("try:\n    import yaml\nexcept (OSError, ModuleNotFoundError):\n"
                            "    yaml = None\n") == {"yaml"}
    # imported plainly too, caught by another exception, or in the try's else: required
    assert optional_modules("import yaml\ntry:\n    import yaml\nexcept ImportError:\n"
                            "    pass\n") == set()
    assert optional_modules("try:\n    import yaml\nexcept KeyError:\n    pass\n") == set()
    # a handler that raises makes it required still
    assert optional_modules("try:\n    import yaml\nexcept ImportError as e:\n"
                            "    raise RuntimeError('need yaml') from e\n") == set()
    assert optional_modules("try:\n    pass\nexcept ImportError:\n    pass\nelse:\n"
                            "    import yaml\n") == set()


def test_a_missing_optional_import_is_no_warning(tmp_path: Path, caplog) -> None:
    """A console script's fallback import (importlib_metadata, absent on Python >= 3.8) is not
    reported as missing; a plain import of a missing module still is."""
    ws = Workspace(tmp_path / "ws")
    script = ws.install / "pkg" / "lib" / "pkg" / "py_node"
    script.parent.mkdir(parents=True)
    script.write_text("#!/usr/bin/python3\n" + CONSOLE_SCRIPT.replace(
        "importlib_metadata", "no_such_fallback_module") + "import no_such_module_anywhere\n")
    resolved = tmp_path / "resolved"
    resolved.mkdir()
    (resolved / "rosdep.json").write_text(json.dumps(
        {"all": {"apt": [], "pip": []}, "exec": {"apt": [], "pip": []}}))
    settings = load_settings(environ={"BASE_IMAGE": "b"}, project_dir=tmp_path)
    with caplog.at_level("INFO"):
        report = lean_resolution(ws, settings, resolved, tmp_path / "lean")
    assert report["not_found"] == ["no_such_module_anywhere (imported by pkg/lib/pkg/py_node)"]
    assert report["optional_not_found"] == [
        "no_such_fallback_module (imported by pkg/lib/pkg/py_node)"]
    warned = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert not any("no_such_fallback_module" in line for line in warned), warned
