"""The lock's pure logic: parsing apt's and pip's resolution, pins, stale inputs, base image."""

import json
from pathlib import Path

import pytest

from docker_ros.core.loading import host_platform
from docker_ros.in_image.runtime import lock, lockapt, lockfile, lockpip


def test_apt_simulation_gives_every_package_with_its_version():
    lines = [
        "NOTE: This is only a simulation!",
        "Inst libfoo1 (1.2-3 Debian:12.5/stable [amd64])",
        "Inst foo [0.9-1] (1.0-1 Debian:12.5/stable [amd64])",
        "Conf libfoo1 (1.2-3 Debian:12.5/stable [amd64])",
    ]
    assert lockapt.parse_apt_simulation(lines) == {"libfoo1": "1.2-3", "foo": "1.0-1"}


def test_pip_report_gives_versions_and_hashes():
    report = {"install": [
        {"metadata": {"name": "Six_Py", "version": "1.16.0"},
         "download_info": {"archive_info": {"hashes": {"sha256": "ab"}}}},
        {"metadata": {"name": "toml", "version": "0.10.2"}, "download_info": {}},
    ]}
    assert lockpip.parse_pip_report(report) == {
        "six-py": {"version": "1.16.0", "sha256": "ab"}, "toml": {"version": "0.10.2"}}


def test_apt_pins_hold_dependencies_and_name_what_is_not_locked():
    locked = {"foo": "1.0-1", "libfoo1": "1.2-3"}
    assert lockapt.apt_pins(["foo/bookworm"], locked) == ["foo=1.0-1", "libfoo1=1.2-3"]
    with pytest.raises(lockfile.LockError,
                       match=r"apt package\(s\) bar not in docker-ros.lock.*lock"):
        lockapt.apt_pins(["foo", "bar=2"], locked)


def test_pip_constraints_hold_every_locked_version_and_need_recorded_versions(tmp_path):
    from docker_ros.in_image.runtime.workspace import Workspace

    locked = {"six": {"version": "1.16.0"}, "idna": {"version": "3.4", "sha256": "ab"}}
    assert lockpip.pip_constraints(locked) == ["idna==3.4", "six==1.16.0"]
    # a lock without pip versions (no report where it was written): installed as written
    assert lockpip.pip_constraints({}) is None
    ws = Workspace(tmp_path)
    args = lock.constrained(ws, ["six"], ["six==1.16.0"], dry_run=False)
    assert args[:1] == ["-c"] and args[2:] == ["six"]
    assert Path(args[1]).read_text() == "six==1.16.0\n"
    assert lock.constrained(ws, [], ["six==1.16.0"], dry_run=False) == []


def test_repos_are_pinned_to_locked_commits_and_a_changed_url_is_stale():
    repos = {"foo": {"type": "git", "url": "file:///r/foo", "version": "main"}}
    locked = {"src/upstream/foo": {"url": "file:///r/foo", "commit": "a" * 40}}
    pinned = lockfile.pin_repos(repos, locked, "src/upstream")
    assert pinned["foo"]["version"] == "a" * 40
    assert 'version: "' + "a" * 40 + '"' in lockfile.dump_repos(pinned)
    moved = {"foo": {"type": "git", "url": "file:///r/other", "version": "main"}}
    with pytest.raises(lockfile.LockError, match="src/upstream/foo"):
        lockfile.pin_repos(moved, locked, "src/upstream")


def test_stale_inputs_name_each_change():
    recorded = {"debs": ["a"], "rosdep_keys": ["boost"], "rosdep_rules": "sha256:1",
                "repos": {"src/upstream/foo": "main"}}
    current = {"debs": ["a", "b"], "rosdep_keys": ["boost", "eigen"], "rosdep_rules": "sha256:2",
               "repos": {"src/upstream/foo": "main"}}
    assert lockfile.stale_inputs(recorded, current) == [
        "debs: added b", "rosdep_keys: added eigen", "rosdep_rules: sha256:1 -> sha256:2"]
    assert lockfile.stale_inputs(recorded, recorded) == []
    with pytest.raises(lockfile.LockError, match="rosdep_keys: added eigen.*run `inv lock`"):
        lockfile.check_inputs({"inputs": recorded}, current)


def test_lock_text_is_stable_and_loads_back(tmp_path: Path):
    data = {"targets": {"run/amd64": {"apt": {"b": "1", "a": "2"}}}, "format": 1}
    text = lockfile.dump_lock(data)
    assert text == lockfile.dump_lock(json.loads(text))
    assert text.index('"a"') < text.index('"b"')
    path = tmp_path / lockfile.LOCK_FILE
    path.write_text(text)
    locked = lockfile.locked_target(lockfile.load_lock(path), "run", "amd64")
    assert locked["apt"] == {"a": "2", "b": "1"}
    assert lockfile.lock_digest(text).startswith("sha256:")
    with pytest.raises(lockfile.LockError, match="no entry for dev/amd64: run `inv lock`$"):
        lockfile.locked_target(lockfile.load_lock(path), "dev", "amd64")
    with pytest.raises(lockfile.LockError, match="no entry for host/amd64: run `inv lock --host`"):
        lockfile.locked_target(lockfile.load_lock(path), "host", "amd64")
    with pytest.raises(lockfile.LockError, match="not found: run `inv lock`"):
        lockfile.load_lock(tmp_path / "missing.lock")


def test_base_image_by_digest():
    record = {"digest": "sha256:" + "f" * 64, "local": False}
    assert lockfile.base_image_ref("reg:5000/ros:noetic", record) == (
        "reg:5000/ros@sha256:" + "f" * 64)
    assert lockfile.base_image_ref("ros", record) == "ros@sha256:" + "f" * 64
    local = {"digest": "sha256:" + "e" * 64, "local": True}
    assert lockfile.base_image_ref("docker-ros/ros1:bookworm", local) == (
        "docker-ros/ros1:docker-ros-lock-" + "e" * 16)  # (BuildKit takes no image ID)
    with pytest.raises(lockfile.LockError, match="no digest for BASE_IMAGE"):
        lockfile.base_image_ref("ros", {})


def test_base_image_record_prefers_the_registry_digest_of_its_repository():
    from docker_ros.host.lock import base_image_record

    attrs = {"Id": "sha256:" + "1" * 64,
             "RepoDigests": ["other/x@sha256:" + "2" * 64, "reg:5000/ros@sha256:" + "3" * 64]}
    assert base_image_record("reg:5000/ros:noetic", attrs) == {
        "ref": "reg:5000/ros:noetic", "digest": "sha256:" + "3" * 64, "local": False}
    local = base_image_record("docker-ros/ros1:bookworm", {"Id": "sha256:" + "1" * 64})
    assert local == {"ref": "docker-ros/ros1:bookworm", "digest": "sha256:" + "1" * 64,
                     "local": True}
    with pytest.raises(lockfile.LockError, match="BASE_IMAGE nothere not found"):
        base_image_record("nothere", None)


def _plan(tmp_path: Path, target: str = "run", **environ):
    from docker_ros.core.loading import load_settings
    from docker_ros.host import buildplan

    s = load_settings(environ={"BASE_IMAGE": "reg:5000/ros:noetic", "BUILD_CONTEXT": str(tmp_path),
                               **environ}, project_dir=tmp_path)
    return buildplan.plan_build(s, target=target, platform="amd64", tools_image="tools:x",
                            tag="img:t", secrets={})


def test_unlocked_builds_are_unchanged_and_a_locked_one_builds_from_the_digest(tmp_path: Path):
    digest = "sha256:" + "3" * 64
    (tmp_path / lockfile.LOCK_FILE).write_text(lockfile.dump_lock({"format": 1, "targets": {
        "run/amd64": {"base_image": {"ref": "reg:5000/ros:noetic", "digest": digest,
                                     "local": False}}}}))
    default = _plan(tmp_path)
    assert _plan(tmp_path, LOCKED="false") == default
    assert "BASE_IMAGE=reg:5000/ros:noetic" in default
    locked = _plan(tmp_path, LOCKED="true")
    assert "BASE_IMAGE=reg:5000/ros@" + digest in locked
    assert "DOCKER_ROS_LOCKED=true" in locked
    label = locked[locked.index("--label") + 1]
    assert label == "org.docker-ros.lock=" + lockfile.lock_digest(
        (tmp_path / lockfile.LOCK_FILE).read_text())
    changed = ("BASE_IMAGE=", "DOCKER_ROS_LOCKED=", "org.docker-ros.lock=")

    def kept(argv):  # each `--flag value` pair, without the ones a locked build changes
        pairs = [(a, b) for a, b in zip(argv, argv[1:]) if a.startswith("--")]
        return [p for p in pairs if not p[1].startswith(changed)]

    assert kept(locked) == kept(default)
    with pytest.raises(lockfile.LockError, match="BASE_IMAGE is other:1, docker-ros.lock has"):
        _plan(tmp_path, LOCKED="true", BASE_IMAGE="other:1")
    with pytest.raises(lockfile.LockError, match="no entry for dev/amd64"):
        _plan(tmp_path, "dev", LOCKED="true")


def _locked_ws(tmp_path: Path, debs: str, inputs):
    from docker_ros.core.loading import load_settings
    from docker_ros.in_image.runtime.workspace import Workspace

    ws = Workspace(tmp_path / "ws")
    ws.target.mkdir(parents=True)
    (ws.target / "debs.txt").write_text(debs)
    entry = {"inputs": {"debs": inputs}, "apt": {"sl": "5.02-1+b1", "libncurses6": "6.4-4"}}
    (ws.target / lockfile.LOCK_FILE).write_text(lockfile.dump_lock(
        {"format": 1, "targets": {f"host/{host_platform()}": entry}}))
    settings = load_settings(environ={"ADDITIONAL_DEBS_FILE": "debs.txt", "LOCKED": "true"},
                             project_dir=ws.target)
    return ws, settings


def test_locked_debs_step_installs_the_locked_versions(tmp_path: Path, capsys):
    from docker_ros.in_image.steps import debs

    ws, settings = _locked_ws(tmp_path, "sl\n", ["sl"])
    debs.main(ws, settings, dry_run=True)
    assert "--no-install-recommends libncurses6=6.4-4 sl=5.02-1+b1" in capsys.readouterr().out


def test_locked_debs_step_stops_on_a_new_line_naming_it(tmp_path: Path):
    from docker_ros.in_image.runtime.workspace import StepError
    from docker_ros.in_image.steps import debs

    ws, settings = _locked_ws(tmp_path, "sl\ncmatrix\n", ["sl"])
    with pytest.raises(StepError, match="debs: added cmatrix.*run `inv lock`"):
        debs.main(ws, settings, dry_run=True)


def test_locked_rosdep_plan_pins_and_names_a_new_dependency(tmp_path: Path):
    from docker_ros.in_image.runtime.workspace import StepError

    ws, settings = _locked_ws(tmp_path, "", [])
    data = json.loads((ws.target / lockfile.LOCK_FILE).read_text())
    data["targets"][f"host/{host_platform()}"]["inputs"].update(
        {"rosdep_apt_all": ["sl"], "rosdep_pip_all": []})
    (ws.target / lockfile.LOCK_FILE).write_text(lockfile.dump_lock(data))
    plan = {"all": {"apt": ["sl"], "pip": []}}
    pinned = lock.locked_rosdep_plan(ws, settings, plan, "all", "rosdep")
    assert pinned["all"] == {"apt": ["libncurses6=6.4-4", "sl=5.02-1+b1"], "pip": []}
    grown = {"all": {"apt": ["sl", "cmatrix"], "pip": []}}
    with pytest.raises(StepError, match="rosdep_apt_all: added cmatrix.*run `inv lock`"):
        lock.locked_rosdep_plan(ws, settings, grown, "all", "rosdep")


def test_recorded_inputs_are_what_the_collect_phases_wrote(tmp_path: Path):
    from docker_ros.in_image.runtime.workspace import Workspace

    ws = Workspace(tmp_path)
    ws.write_state("debs.json", {"packages": ["sl", "cmatrix"]})
    ws.write_state("rosdep.json", {"all": {"apt": ["b", "a"], "pip": []}})
    rules = tmp_path / "rules.yaml"
    rules.write_text("boost: {debian: [libboost-all-dev]}\n")
    inputs = lock.recorded_inputs(ws, rules)
    assert inputs == {"debs": ["cmatrix", "sl"], "pip": [], "pip_constraints": [],
                      "rosdep_apt_all": ["a", "b"], "rosdep_pip_all": [],
                      "rosdep_rules": lockfile.file_digest(rules)}
    # every kind is compared: a new <depend> (rosdep's apt set) names itself
    grown = {**inputs, "rosdep_apt_all": ["a", "b", "c"]}
    assert lockfile.stale_inputs(inputs, grown) == ["rosdep_apt_all: added c"]
    rules.write_text("boost: {debian: [libboost-dev]}\n")
    assert lockfile.stale_inputs(inputs, lock.recorded_inputs(ws, rules))[0].startswith(
        "rosdep_rules: sha256:")


def test_a_locked_apt_version_apt_cannot_find_is_named_with_the_sources(tmp_path: Path):
    output = ("E: Version '0.0-gone1' for 'cmatrix' was not found\n"
              "E: Version '2.0' for 'libfoo1' was not found\n")
    assert lockapt.missing_versions(output) == ["cmatrix=0.0-gone1", "libfoo1=2.0"]
    (tmp_path / "sources.list.d").mkdir()
    (tmp_path / "sources.list").write_text("deb http://deb.debian.org/debian bookworm main\n"
                                           "# deb http://off/ x main\n")
    (tmp_path / "sources.list.d" / "ros.sources").write_text(
        "Types: deb\nURIs: http://packages.ros.org/ros2/ubuntu\nSuites: noble\n")
    assert lockapt.apt_sources(tmp_path) == ["http://deb.debian.org/debian bookworm",
                                          "http://packages.ros.org/ros2/ubuntu noble"]


def test_which_entry_a_step_honours():
    assert lockfile.default_target({}) == "host"
    assert lockfile.default_target({"DOCKER_ROS": "1"}) == "dev"  # image: imports, resolve
    assert lockfile.default_target({"DOCKER_ROS": "1", lockfile.TARGET_ENV: "run"}) == "run"
    assert lockfile.is_locked(object(), {lockfile.LOCKED_ENV: "true"})
    assert not lockfile.is_locked(object(), {})


def test_a_step_honours_the_entry_of_the_platform_it_runs_on(tmp_path: Path, monkeypatch):
    """A locked arm64 build: its steps run on an aarch64 machine (QEMU's, as an arm64 image
    says `uname -m`: test_multiarch's GitLab test) and honour the arm64 entries; the host
    gives that build the arm64 entries' prepare pins and base image. (Was a locked arm64 image
    build of 5 minutes under QEMU; a locked build installing its entry is
    tests/docker/test_lock.py's.)"""
    import os

    from docker_ros.core.loading import load_settings
    from docker_ros.host.lockpins import locked_build_args, prepare_pins
    from docker_ros.in_image.runtime.workspace import Workspace

    def entry(arch: str, version: str) -> dict:
        return {"base_image": {"ref": "reg:5000/ros:noetic", "digest": f"sha256:{version * 64}",
                               "local": False},
                "prepare": {"tini": version}, "apt": {"sl": version}}

    ws = Workspace(tmp_path / "ws")
    ws.target.mkdir(parents=True)
    (ws.target / lockfile.LOCK_FILE).write_text(lockfile.dump_lock({"format": 1, "targets": {
        f"{target}/{arch}": entry(arch, version) for target in ("dev", "run")
        for arch, version in (("amd64", "1"), ("arm64", "2"))}}))
    settings = load_settings(environ={"LOCKED": "true", "BASE_IMAGE": "reg:5000/ros:noetic",
                                      "BUILD_CONTEXT": str(ws.target)},
                             project_dir=ws.target)
    real = os.uname()
    for machine, version in (("aarch64", "2"), ("x86_64", "1")):
        faked = os.uname_result((*real[:4], machine))
        monkeypatch.setattr(os, "uname", lambda faked=faked: faked)
        monkeypatch.setenv(lockfile.TARGET_ENV, "run")
        assert lockfile.active_entry(ws, settings, "debs")["apt"] == {"sl": version}
    pins = prepare_pins(settings, "arm64")
    assert lockapt.parse_apt_preferences(pins["base.pref"]) == {"tini": "2"}
    assert locked_build_args(settings, target="run", platform="arm64")["BASE_IMAGE"] == (
        "reg:5000/ros@sha256:" + "2" * 64)


def test_entry_changes_name_each_difference_by_entry():
    from docker_ros.host.lock import entry_changes

    old = {"inputs": {"debs": ["sl"]}, "apt": {"sl": "1"}, "pip": {"six": {"version": "1"}},
           "repos": {"upstream/a": {"url": "u", "commit": "c1"}},
           "base_image": {"digest": "sha256:1"}}
    new = {**old, "inputs": {"debs": ["sl", "cmatrix"]}, "apt": {"sl": "2"},
           "base_image": {"digest": "sha256:2"}}
    assert entry_changes("run/amd64", old, new) == [
        "run/amd64: debs: added cmatrix", "run/amd64: apt sl 1 -> 2",
        "run/amd64: base_image sha256:1 -> sha256:2"]
    assert entry_changes("run/amd64", old, old) == []


def test_lock_status_says_whether_a_lock_is_in_use(tmp_path: Path):
    from docker_ros.core.loading import load_settings
    from docker_ros.host.lockpins import lock_status

    def status(**environ):
        return lock_status(load_settings(environ={"BUILD_CONTEXT": str(tmp_path), **environ},
                                         project_dir=tmp_path))

    assert status() == "lock: not in use (LOCKED=false)"
    assert "docker-ros.lock is missing: run `inv lock`" in status(LOCKED="true")
    text = lockfile.dump_lock({"format": 1, "targets": {"dev/amd64": {}, "run/amd64": {}}})
    (tmp_path / lockfile.LOCK_FILE).write_text(text)
    assert status() == "lock: not in use (LOCKED=false; docker-ros.lock present)"
    digest = lockfile.lock_digest(text)
    assert status(LOCKED="true") == (f"lock: locked build, docker-ros.lock {digest}"
                                     " (dev/amd64, run/amd64)")


def test_a_locked_build_takes_the_lock_into_its_imports_even_with_a_hook(tmp_path: Path):
    from docker_ros.core.loading import load_settings
    from docker_ros.host import buildcontext

    (tmp_path / ".repos").write_text("repositories: {}\n")
    (tmp_path / lockfile.LOCK_FILE).write_text(lockfile.dump_lock({"format": 1, "targets": {}}))

    def imports(**environ):
        return buildcontext.import_inputs(load_settings(environ=environ, project_dir=tmp_path),
                                   tmp_path)

    assert imports() == [".repos"]  # unlocked: the imports image is unchanged
    assert imports(LOCKED="true") == [lockfile.LOCK_FILE, ".repos"]
    (tmp_path / "docker").mkdir()
    (tmp_path / "docker" / "before_dependency_identification.sh").write_text("true\n")
    assert imports() == []
    assert imports(LOCKED="true") == [lockfile.LOCK_FILE]


def test_a_locked_pip_version_pip_cannot_find_is_named_with_the_sources():
    stderr = ("ERROR: Could not find a version that satisfies the requirement "
              "docker_ros_lock_probe (from versions: 1.0, 1.1)\n"
              "ERROR: No matching distribution found for docker_ros_lock_probe\n")
    constraints = ["docker-ros-lock-probe==0.9", "six==1.16.0"]
    assert lockpip.unavailable_pins(stderr, constraints) == ["docker-ros-lock-probe==0.9"]
    impossible = ("ERROR: Cannot install docker_ros_lock_probe because these package versions "
                  "have conflicting dependencies.\n    The user requested docker_ros_lock_probe\n"
                  "    The user requested (constraint) docker-ros-lock-probe==0.9\n"
                  "ERROR: ResolutionImpossible: for help visit https://pip.pypa.io/\n")
    assert lockpip.unavailable_pins(impossible, constraints) == ["docker-ros-lock-probe==0.9"]
    requirements = ["--no-index --find-links http://127.0.0.1:8000/w/", "docker_ros_lock_probe"]
    assert lockpip.pip_sources(requirements, {}) == ["http://127.0.0.1:8000/w/"]
    assert lockpip.pip_sources(["six"], {}) == ["https://pypi.org/simple (pip's default index)"]
    assert lockpip.pip_sources(["six"], {"PIP_INDEX_URL": "http://mirror/simple"}) == [
        "http://mirror/simple"]


DPKG_STATUS = """Package: tini
Status: install ok installed
Version: 0.19.0-1
Description: tiny init
 a continuation line: with a colon

Package: gone
Status: deinstall ok config-files
Version: 1.0

Package: libc6
Status: install ok installed
Architecture: amd64
Version: 2.36-9+deb12u4
"""


def test_dpkg_status_gives_installed_packages_and_what_changed_since():
    installed = lockapt.parse_dpkg_status(DPKG_STATUS)
    assert installed == {"tini": "0.19.0-1", "libc6": "2.36-9+deb12u4"}
    after = {**installed, "libc6": "2.36-9+deb12u5", "g++": "4:12.2.0-3"}
    assert lockapt.installed_over(installed, after) == {"g++": "4:12.2.0-3",
                                                      "libc6": "2.36-9+deb12u5"}
    assert lockapt.installed_over(installed, installed) == {}


def test_apt_preferences_hold_each_locked_version_and_read_back():
    pins = {"tini": "0.19.0-1", "g++": "4:12.2.0-3"}
    text = lockapt.apt_preferences(pins)
    assert text.startswith(lockapt.PREFERENCES_HEADER
                           + "Package: g++\nPin: version 4:12.2.0-3\nPin-Priority: 1001\n\n")
    assert lockapt.parse_apt_preferences(text) == pins
    assert lockapt.apt_preferences({}) == lockapt.PREFERENCES_HEADER  # a lock of nothing: not empty


def test_an_install_otherwise_than_the_lock_names_each_difference():
    pins = {"tini": "0.19.0-1", "libtini": "0.19.0-1"}
    before = {"libc6": "2.36"}
    assert lockapt.unlocked_installs(pins, before, {**before, **pins}) == []
    after = {**before, "tini": "0.20-1", "curl": "7.88"}
    assert lockapt.unlocked_installs(pins, before, after) == [
        "curl 7.88 (not in docker-ros.lock)", "libtini=0.19.0-1 (missing)",
        "tini=0.19.0-1 (installed 0.20-1)"]


def test_the_prepare_pins_are_the_run_and_dev_entries_and_an_old_lock_is_refused(
        tmp_path: Path):
    from docker_ros.core.loading import load_settings
    from docker_ros.host.lockpins import prepare_pins

    entries = {"run/amd64": {"prepare": {"tini": "1"}},
               "dev/amd64": {"prepare": {"tini": "1", "g++": "2"}}}
    lock_text = lockfile.dump_lock({"format": 1, "targets": entries})
    (tmp_path / lockfile.LOCK_FILE).write_text(lock_text)

    def pins(**environ):
        return prepare_pins(load_settings(environ={"BUILD_CONTEXT": str(tmp_path), **environ},
                                          project_dir=tmp_path), "amd64")

    assert pins() == {}  # unlocked: no pins, an empty /lock in the imports image
    assert {k: lockapt.parse_apt_preferences(v) for k, v in pins(LOCKED="true").items()} == {
        "base.pref": {"tini": "1"}, "dev.pref": {"tini": "1", "g++": "2"}}
    del entries["dev/amd64"]["prepare"]
    lock_text = lockfile.dump_lock({"format": 1, "targets": entries})
    (tmp_path / lockfile.LOCK_FILE).write_text(lock_text)
    with pytest.raises(lockfile.LockError,
                       match="dev/amd64 records no prepare packages .*inv lock"):
        pins(LOCKED="true")


def test_the_installed_closure_follows_dependencies_alternatives_and_virtual_packages():
    status = "\n\n".join([
        "Package: sl\nStatus: install ok installed\nVersion: 5.02-1+b1\n"
        "Depends: libc6 (>= 2.34), libncurses6 (>= 6) | libncursesw6, mail-transport-agent",
        "Package: libncurses6\nStatus: install ok installed\nVersion: 6.4-4\n"
        "Pre-Depends: libtinfo6:any (= 6.4-4)",
        "Package: libtinfo6\nStatus: install ok installed\nVersion: 6.4-4\nDepends: libc6",
        "Package: libc6\nStatus: install ok installed\nVersion: 2.36-9\nDepends: libgcc-s1",
        "Package: libgcc-s1\nStatus: install ok installed\nVersion: 12.2.0-14\nDepends: libc6",
        "Package: exim4\nStatus: install ok installed\nVersion: 4.96-15\n"
        "Provides: mail-transport-agent",
        "Package: libyaml-cpp-dev\nStatus: install ok installed\nVersion: 0.7.0+dfsg-8",
        "Package: removed\nStatus: deinstall ok config-files\nVersion: 1"])
    assert lockapt.installed_closure(["sl=5.02-1+b1"], status) == {
        "exim4": "4.96-15", "libc6": "2.36-9", "libgcc-s1": "12.2.0-14",
        "libncurses6": "6.4-4", "libtinfo6": "6.4-4", "sl": "5.02-1+b1"}
    assert lockapt.installed_closure(["removed", "absent"], status) == {}


def test_python_debs_are_the_closure_s_python_packages_at_their_versions() -> None:
    closure = {"cmatrix": "2.0-3", "python3-termcolor": "1.1.0-4", "python-is-python3": "3.11.2-1",
               "libpython3.11": "3.11.2-6", "python3": "3.11.2-1"}
    assert lockapt.python_debs(closure) == ["python-is-python3=3.11.2-1",
                                         "python3-termcolor=1.1.0-4"]
    assert lockapt.python_debs({"cmatrix": "2.0-3"}) == []
