"""`inv dev-shell`'s `docker run` argv (a pure function), X11/GPU detection and the X cookie."""

import os
import struct
import subprocess
import sys
from pathlib import Path

import pytest

from docker_ros.core.loading import load_settings
from docker_ros.host import devshell
from docker_ros.host.devshell import HostUser, ShellOptions

REF = "robot:latest-dev"
USER = HostUser(1234, 1235, "alice", tty=False, cwd=Path("/home/alice/robot"))


def settings(tmp_path: Path):
    return load_settings(environ={"BASE_IMAGE": "base:1", "BUILD_CONTEXT": str(tmp_path)},
                         project_dir=tmp_path)


def argv(tmp_path: Path, user: HostUser = USER, **options) -> list:
    return devshell.dev_shell_argv(settings(tmp_path), REF, ShellOptions(**options), user)


def pairs(args: list, flag: str) -> list:
    return [args[i + 1] for i, a in enumerate(args) if a == flag]


def test_default_is_an_interactive_shell_with_repository_and_user(tmp_path):
    args = argv(tmp_path)
    assert args[:4] == ["docker", "run", "--rm", "-i"] and "-t" not in args
    assert pairs(args, "-v") == [f"{tmp_path}:/docker-ros/ws/src/target"]
    assert pairs(args, "-e") == ["DOCKER_UID=1234", "DOCKER_GID=1235", "DOCKER_USER=alice"]
    assert args[-2:] == [REF, "bash"]
    assert "-t" in argv(tmp_path, HostUser(1234, 1235, "alice", tty=True))


def test_root_is_not_mapped(tmp_path):
    assert not [e for e in pairs(argv(tmp_path, HostUser(0, 0, "root")), "-e")
                if e.startswith("DOCKER_")]


def test_command_runs_non_interactively(tmp_path):
    assert argv(tmp_path, command="colcon build && exit 3")[-4:] == [
        REF, "bash", "-c", "colcon build && exit 3"]


def test_mounts_env_network_devices(tmp_path):
    args = argv(tmp_path, volumes=("./data:/data:ro", "~/.ccache:/ccache", "cache:/c",
                                   "/abs:/abs"),
                env=("ROS_DOMAIN_ID=7", "HOME_TOKEN"), network="host", name="dev1",
                privileged=True, devices=("/dev/ttyUSB0",))
    assert pairs(args, "-v")[1:] == [
        "/home/alice/robot/data:/data:ro", f"{Path.home()}/.ccache:/ccache", "cache:/c",
        "/abs:/abs"]
    assert pairs(args, "-e")[3:] == ["ROS_DOMAIN_ID=7", "HOME_TOKEN"]
    assert pairs(args, "--network") == ["host"] and pairs(args, "--ipc") == ["host"]
    assert pairs(args, "--name") == ["dev1"] and "--privileged" in args
    assert pairs(args, "--device") == ["/dev/ttyUSB0"]
    assert pairs(argv(tmp_path, network="ros"), "--ipc") == []
    assert args.index(REF) == len(args) - 2  # every option before the image


def test_x11_and_gpus(tmp_path):
    args = argv(tmp_path, x11_display=":1", xauthority="/tmp/x/xauth", gpus="all")
    assert "DISPLAY=:1" in pairs(args, "-e") and "XAUTHORITY=/tmp/.docker-ros.xauth" in args
    assert "/tmp/.X11-unix:/tmp/.X11-unix" in pairs(args, "-v")
    assert "/tmp/x/xauth:/tmp/.docker-ros.xauth:ro" in pairs(args, "-v")
    assert pairs(args, "--gpus") == ["all"]
    assert "NVIDIA_DRIVER_CAPABILITIES=all" in pairs(args, "-e")
    plain = argv(tmp_path)
    assert "--gpus" not in plain and not [e for e in pairs(plain, "-e") if "DISPLAY" in e]
    no_cookie = argv(tmp_path, x11_display=":1")
    assert "DISPLAY=:1" in no_cookie and not [a for a in no_cookie if "XAUTHORITY" in a]


def test_x11_auto_needs_a_local_display_with_its_socket(tmp_path):
    (tmp_path / "X1").touch()
    assert devshell.select_x11("auto", ":1", tmp_path)
    assert devshell.select_x11("auto", "unix:1.0", tmp_path)
    assert not devshell.select_x11("auto", ":0", tmp_path)  # no socket X0
    assert not devshell.select_x11("auto", "", tmp_path)
    assert not devshell.select_x11("auto", "localhost:10.0", tmp_path)  # ssh -X: TCP
    assert devshell.select_x11("true", "localhost:10.0", tmp_path)
    assert not devshell.select_x11("no", ":1", tmp_path)
    with pytest.raises(devshell.DevShellError, match="DISPLAY is not set"):
        devshell.select_x11("true", "", tmp_path)
    with pytest.raises(devshell.DevShellError, match="auto, true or false"):
        devshell.select_x11("maybe", ":1", tmp_path)


def test_gpus_auto_follows_the_nvidia_runtime():
    assert devshell.select_gpus("auto", ["io.containerd.runc.v2", "nvidia", "runc"]) == "all"
    assert devshell.select_gpus("auto", ["io.containerd.runc.v2", "runc"]) == ""
    assert devshell.select_gpus("none", ["nvidia"]) == ""
    assert devshell.select_gpus("device=0", []) == "device=0"


def xauth_entry(family: int, address: bytes, number: bytes, cookie: bytes) -> bytes:
    out = struct.pack(">H", family)
    for value in (address, number, b"MIT-MAGIC-COOKIE-1", cookie):
        out += struct.pack(">H", len(value)) + value
    return out


def test_cookie_of_the_display_made_valid_for_any_host(tmp_path):
    data = (xauth_entry(256, b"laptop", b"0", b"\x01" * 16)
            + xauth_entry(256, b"laptop", b"1", b"\x02" * 16)
            + xauth_entry(0, b"\x7f\x00\x00\x01", b"1", b"\x03" * 16))
    entries = list(devshell.xauth_entries(devshell.wildcard_cookies(data, "1")))
    assert [(e[0], e[2], e[4]) for e in entries] == [
        (0xFFFF, b"1", b"\x02" * 16), (0xFFFF, b"1", b"\x03" * 16)]
    assert list(devshell.xauth_entries(data[:-3])) == list(devshell.xauth_entries(data))[:2]
    xauthority = tmp_path / "Xauthority"
    xauthority.write_bytes(data)
    cookie = devshell.write_cookie(":0", {"XAUTHORITY": str(xauthority)}, tmp_path / "out")
    assert cookie == str(tmp_path / "out")
    assert [e[4] for e in devshell.xauth_entries(Path(cookie).read_bytes())] == [b"\x01" * 16]
    assert oct(Path(cookie).stat().st_mode & 0o777) == "0o600"
    assert devshell.write_cookie(":0", {"XAUTHORITY": str(tmp_path / "none")},
                                 tmp_path / "x") == ""


def test_display_names():
    assert devshell.parse_display(":0") == ("", "0")
    assert devshell.parse_display("unix:2.0") == ("unix", "2")
    assert devshell.parse_display("localhost:10.0") == ("localhost", "10")
    assert devshell.parse_display("wayland-0") is None


def test_dry_run_prints_the_docker_run_with_repeated_flags(tmp_path):
    (tmp_path / ".env").write_text("BASE_IMAGE=base:1\nIMAGE=robot:1\n")
    result = subprocess.run(
        [sys.executable, "-m", "docker_ros", "dev-shell", "--dry-run", "-c", "exit 3",
         "--volume", "/a:/a", "--volume", "/b:/b", "--env", "X=1", "--network", "host",
         "--x11", "false", "--gpus", "none"],
        cwd=tmp_path, capture_output=True, text=True,
        env={k: v for k, v in os.environ.items() if k not in ("IMAGE", "TARGET", "COMMAND")})
    assert result.returncode == 0, result.stderr
    line = result.stdout.strip()
    assert line.startswith("docker run --rm -i")
    assert "-v /a:/a -v /b:/b -e X=1 --network host --ipc host robot:1-dev bash -c 'exit 3'" in line


def test_volume_specs_are_checked_in_our_words():
    for good in ("./data:/data:ro", "~/.ccache:/ccache", "cache:/c", "/abs:/abs:rw,z"):
        assert devshell.volume_problem(good) == "", good
    assert devshell.volume_problem("bad:::") == (
        "--volume 'bad:::': 3 ':' (one or two belong); use HOST:CONTAINER[:MODE], e.g. "
        "./data:/data:ro or a volume name, ccache:/ccache")
    assert "no ':'" in devshell.volume_problem("/data")
    assert "host side (before ':') is empty" in devshell.volume_problem(":/data")
    assert "'my data' is neither a path" in devshell.volume_problem("my data:/data")
    assert "container side 'data' must be an absolute path" in devshell.volume_problem("./d:data")
    assert "unknown mode 'rx'" in devshell.volume_problem("./d:/d:ro,rx")
    with pytest.raises(devshell.DevShellError, match="'x:y'.*; --volume 'bad:::'"):
        devshell.check_shell_options(["./ok:/ok", "x:y", "bad:::"])


def test_env_values_are_checked_before_the_build():
    for good in ("ROS_DOMAIN_ID=3", "DISPLAY", "A_1=x=y", "EMPTY=", "my-var=1", "a.b=c"):
        assert devshell.env_problem(good) == "", good
    for bad in ("=x", "MY VAR=x", ""):
        assert "give NAME=VALUE (or NAME)" in devshell.env_problem(bad), bad
    with pytest.raises(devshell.DevShellError, match="--env '=x'"):
        devshell.check_shell_options(["./ok:/ok"], ["A=1", "=x"])


def test_a_builder_keeping_images_in_another_engine_stops_the_shell_first(tmp_path,
                                                                          monkeypatch):
    """BUILDER=<docker context of another engine>: the dev image would be built there and
    `docker run` (the CLI's engine) would try to pull it from Docker Hub. The task stops before
    building, naming the way that works (DOCKER_CONTEXT)."""
    from docker_ros.host import build, builder, engine, pipeline
    from docker_ros.host.pipeline import TaskError

    other = builder.Builder("e26", "docker", "e26", "unix:///run/e26.sock", True)
    monkeypatch.setattr(build, "selected_builder", lambda settings: other)
    monkeypatch.setattr(engine, "cli_host", lambda environ: "unix:///var/run/docker.sock")
    monkeypatch.setattr(pipeline, "build_targets", lambda *a, **k: pytest.fail("built"))
    monkeypatch.setattr(pipeline.subprocess, "call", lambda argv: pytest.fail("ran"))
    with pytest.raises(TaskError) as stopped:
        pipeline.run_dev_shell(settings(tmp_path), ShellOptions(command="true"), x11="false",
                               rebuild=False, dry_run=False)
    assert "BUILDER 'e26' keeps its images in the engine at unix:///run/e26.sock" in str(
        stopped.value)
    assert "DOCKER_CONTEXT=e26 inv dev-shell" in str(stopped.value)
    local = builder.Builder("default", "docker", "default", "unix:///var/run/docker.sock", False)
    monkeypatch.setattr(build, "selected_builder", lambda settings: local)
    pipeline.check_shell_engine(settings(tmp_path))  # the CLI's own engine: no objection


def test_blacklisted_packages_stay_out_of_colcon_in_the_shell(tmp_path):
    """The mounted repository hides the COLCON_IGNORE files the dev image's copies of the
    blacklisted packages have: the shell gets colcon defaults that ignore them (before the
    user's --env, so that a COLCON_DEFAULTS_FILE of theirs wins)."""
    import json

    (tmp_path / "docker").mkdir()
    (tmp_path / "docker" / "blacklisted-packages.txt").write_text(
        "# not built\nmy_robot_py\nbad_a bad_b  # two on a line\nmy_robot_py\n")
    names = devshell.blacklisted_names(settings(tmp_path))
    assert names == ["my_robot_py", "bad_a", "bad_b"]
    defaults = devshell.write_colcon_defaults(names, tmp_path / "defaults.yaml")
    written = json.loads((tmp_path / "defaults.yaml").read_text())
    assert set(written) == {"build", "test", "list", "graph"}
    assert written["build"] == {"packages-ignore": ["my_robot_py", "bad_a", "bad_b"]}
    args = argv(tmp_path, colcon_defaults=defaults, env=("COLCON_DEFAULTS_FILE=/mine.yaml",))
    envs = [e for e in pairs(args, "-e") if e.startswith("COLCON_DEFAULTS_FILE=")]
    assert envs == [f"COLCON_DEFAULTS_FILE={devshell.COLCON_DEFAULTS_IN_CONTAINER}",
                    "COLCON_DEFAULTS_FILE=/mine.yaml"]
    assert f"{defaults}:{devshell.COLCON_DEFAULTS_IN_CONTAINER}:ro" in pairs(args, "-v")
    # no blacklist: nothing written, nothing mounted
    (tmp_path / "docker" / "blacklisted-packages.txt").unlink()
    assert devshell.blacklisted_names(settings(tmp_path)) == []
    assert devshell.write_colcon_defaults([], tmp_path / "none.yaml") == ""
    assert "COLCON_DEFAULTS_FILE" not in " ".join(argv(tmp_path))


def test_a_colcon_defaults_file_of_the_users_keeps_the_blacklist(tmp_path):
    """`inv dev-shell --env COLCON_DEFAULTS_FILE=<a file of the repository>`: the user's file
    replaced the defaults that ignore the blacklisted packages, so `colcon build` in the shell
    built them again. A file of the repository or of a --volume is merged into ours (its
    settings and its own ignored packages stay); one docker-ros cannot read stays in force,
    with a warning naming the packages."""
    import json

    repo = tmp_path / "repo"
    (repo / "config").mkdir(parents=True)
    (repo / "config" / "colcon.yaml").write_text(
        "build:\n  symlink-install: true\n  packages-ignore: [old_pkg]\n"
        "test-result:\n  verbose: true\n")
    (tmp_path / "extra").mkdir()
    (tmp_path / "extra" / "defaults.json").write_text('{"list": {"names-only": true}}')
    names = ["bad_a", "bad_b"]

    def plan(env, volumes=(), environ=None):
        options = ShellOptions(env=env, volumes=volumes)
        return devshell.shell_colcon_defaults(names, options, repo, tmp_path, environ or {},
                                              tmp_path / "ours.yaml")

    shell, warning = plan(("A=1", f"COLCON_DEFAULTS_FILE={devshell.TARGET}/config/colcon.yaml"))
    assert shell.env == ["A=1"]  # ours is the shell's COLCON_DEFAULTS_FILE, and it says so
    assert warning == (f"docker-ros dev-shell: COLCON_DEFAULTS_FILE={devshell.TARGET}/config/"
                       "colcon.yaml (--env) is merged into the shell's colcon defaults, which "
                       "also ignore the blacklisted packages bad_a, bad_b")
    merged = json.loads((tmp_path / "ours.yaml").read_text())
    assert merged["build"] == {"symlink-install": True,
                               "packages-ignore": ["old_pkg", "bad_a", "bad_b"]}
    assert merged["test"] == {"packages-ignore": ["bad_a", "bad_b"]}
    assert merged["test-result"] == {"verbose": True}
    shell, warning = plan(("COLCON_DEFAULTS_FILE",), ("./extra:/extra:ro",),
                          {"COLCON_DEFAULTS_FILE": "/extra/defaults.json"})
    assert "/extra/defaults.json (--env) is merged" in warning and shell.env == []
    assert json.loads((tmp_path / "ours.yaml").read_text())["list"] == {
        "names-only": True, "packages-ignore": ["bad_a", "bad_b"]}
    # a file only the image has: it stays in force, and the user learns what that means
    shell, warning = plan(("COLCON_DEFAULTS_FILE=/etc/colcon.yaml",))
    assert shell.env == ("COLCON_DEFAULTS_FILE=/etc/colcon.yaml",)
    assert warning.startswith("docker-ros dev-shell: warning: COLCON_DEFAULTS_FILE=/etc/colcon"
                              ".yaml (--env) is no colcon defaults file of the repository")
    assert "builds the blacklisted packages bad_a, bad_b" in warning
    # a file of the repository that is no text: as one docker-ros cannot read (it stopped
    # dev-shell with UnboundLocalError)
    (repo / "config" / "colcon.bin").write_bytes(b"\xff\xfe\x00")
    shell, warning = plan((f"COLCON_DEFAULTS_FILE={devshell.TARGET}/config/colcon.bin",))
    assert warning.startswith("docker-ros dev-shell: warning: ") and len(shell.env) == 1
    # nothing of the user's: ours alone, as before
    shell, warning = plan(())
    assert warning == "" and shell.colcon_defaults == str(tmp_path / "ours.yaml")
    assert json.loads((tmp_path / "ours.yaml").read_text())["graph"] == {
        "packages-ignore": ["bad_a", "bad_b"]}


def test_a_build_for_the_shell_or_slim_makes_only_the_platforms_they_use(tmp_path, monkeypatch):
    """PLATFORM=amd64,arm64: a dev shell needs this machine's dev image, slim slims this
    machine's run image; building the other platform too cost a QEMU build (or failed without
    QEMU). The one built keeps its tag among every platform (`-amd64`)."""
    from docker_ros.host import build, pipeline, refs
    from docker_ros.host.build import BuiltImage

    here = pipeline.host_platform()
    other = "arm64" if here == "amd64" else "amd64"
    built = []

    def build_images(settings, *, targets, platform):
        built.append((platform, dict(targets)))
        return [BuiltImage(t, ref, platform, 0.0) for t, ref in targets.items()]

    monkeypatch.setattr(build, "check_engine", lambda settings=None: None)
    monkeypatch.setattr(refs, "platform_base", lambda settings, platform: ("b:1", ""))
    monkeypatch.setattr(build, "build_images", build_images)
    monkeypatch.setattr(build, "summary_table", lambda images: "")
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "package.xml").write_text(
        "<package format='3'><name>pkg</name><version>0.0.0</version><description>d"
        "</description><maintainer email='a@b.c'>m</maintainer><license>MIT</license></package>")
    s = load_settings(environ={"BASE_IMAGE": "b:1", "BUILD_CONTEXT": str(tmp_path),
                               "PLATFORM": f"{here},{other}", "IMAGE": "reg.example/r:1",
                               "WORKSPACE": str(tmp_path / "ws")}, project_dir=tmp_path)
    pipeline.build_targets(s, ("dev",), dry_run=False, only=[here])
    assert built == [(here, {"dev": f"reg.example/r:1-dev-{here}"})]
    built.clear()
    pipeline.build_targets(s, ("dev",), dry_run=False)
    assert [platform for platform, _ in built] == [here, other]
