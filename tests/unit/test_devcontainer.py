"""devcontainer.json from dev-shell's decisions (pure), the merge with the user's edits, JSONC,
and bad input: one message, nothing written."""

import json
import os
import subprocess
from pathlib import Path

import pytest

from docker_ros.core.loading import load_settings
from docker_ros.host import devcontainer, devshell
from docker_ros.host.devcontainer import DevcontainerError
from docker_ros.host.devshell import HostUser, ShellOptions

REF = "robot:latest-dev"
USER = HostUser(4242, 4343, "alice", cwd=Path("/home/alice"))


def ros_repo(tmp_path: Path) -> Path:
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "package.xml").write_text("<package format='3'><name>pkg</name></package>\n")
    return tmp_path


def settings(tmp_path: Path, **environ: str):
    return load_settings(environ={"BASE_IMAGE": "base:1", "BUILD_CONTEXT": str(tmp_path),
                                  **environ}, project_dir=tmp_path)


def config(tmp_path: Path, user: HostUser = USER, *, display: str = "", gpus: str = "auto",
           image_present: bool = False, **options):
    content, _notes = devcontainer.config_for(
        settings(tmp_path), REF, ShellOptions(**options), user=user, display=display, gpus=gpus,
        image_present=image_present)
    return content


def test_image_workspace_user_and_ros_environment(tmp_path):
    made = config(ros_repo(tmp_path))
    assert made["image"] == REF
    assert made["initializeCommand"]["image"][:4] == ["docker-ros", "build", "--target", "dev"]
    assert made["workspaceMount"] == ("source=${localWorkspaceFolder},"
                                      "target=/docker-ros/ws/src/target,type=bind")
    # the workspace around the repository (colcon there sees the .repos imports too)
    assert made["workspaceFolder"] == "/docker-ros/ws" == str(Path(devshell.TARGET).parents[1])
    # dev-shell's mapping, by the image's entrypoint (which runs: overrideCommand false), of
    # the user the initializeCommand writes when the folder is opened
    assert made["containerEnv"] == {"NVIDIA_DRIVER_CAPABILITIES": "all"}
    assert made["initializeCommand"]["user"][-1] == (
        "${localWorkspaceFolder}/.devcontainer/.docker-ros-user.env")
    assert made["remoteUser"] == "${containerEnv:DOCKER_UID:root}"
    assert made["updateRemoteUserUID"] is False and made["overrideCommand"] is False
    assert made["runArgs"] == [
        "--tty", "--stop-signal=SIGHUP",
        "--env-file=${localWorkspaceFolder}/.devcontainer/.docker-ros-user.env"]
    assert made["userEnvProbe"] == "loginInteractiveShell"
    vscode = made["customizations"]["vscode"]
    assert "ms-vscode.cpptools" in vscode["extensions"]
    assert vscode["settings"]["terminal.integrated.automationProfile.linux"]["args"] == ["-i"]


def test_the_file_is_the_same_for_every_host_user(tmp_path):
    """`--check` passes for any user: the file names none (root included)."""
    repo = ros_repo(tmp_path)
    made = config(repo)
    assert config(repo, HostUser(1000, 1000, "bob", cwd=Path("/home/alice"))) == made
    assert config(repo, HostUser(0, 0, "root", cwd=Path("/home/alice"))) == made
    assert "4242" not in json.dumps(made) and "alice" not in json.dumps(made)


def run_user_script(made: dict, folder: Path, **environ: str) -> str:
    """The initializeCommand's user part, run by sh as Dev Containers runs it (the variable
    expanded); the file it writes."""
    argv = [part.replace("${localWorkspaceFolder}", str(folder))
            for part in made["initializeCommand"]["user"]]
    env = {"PATH": os.environ["PATH"], **environ}
    subprocess.run(argv, check=True, env=env, cwd=str(folder))
    return (folder / ".devcontainer" / ".docker-ros-user.env").read_text()


def test_the_user_who_opens_the_folder_is_mapped(tmp_path):
    """The initializeCommand writes the mapping of whoever runs it (id -u), or of DOCKER_UID/
    DOCKER_GID/DOCKER_USER when set; root maps nobody (an empty file: remoteUser is root)."""
    made = config(ros_repo(tmp_path))
    written = run_user_script(made, tmp_path)
    if os.getuid() == 0:
        assert written == ""
    else:
        assert written.startswith(f"DOCKER_UID={os.getuid()}\nDOCKER_GID={os.getgid()}\n")
    written = run_user_script(made, tmp_path, DOCKER_UID="4242", DOCKER_GID="4343",
                              DOCKER_USER="alice")
    assert written == "DOCKER_UID=4242\nDOCKER_GID=4343\nDOCKER_USER=alice\n"
    assert run_user_script(made, tmp_path, DOCKER_UID="0") == ""
    # (no `${...}` in it: Dev Containers would take it for one of its variables)
    assert "${" not in " ".join(made["initializeCommand"]["user"][:-1])


def test_same_options_as_dev_shell(tmp_path):
    repo = ros_repo(tmp_path)
    made = config(repo, display=":1", gpus="device=0", network="host", privileged=True,
                  devices=("/dev/ttyUSB0",), env=("ROS_DOMAIN_ID=7", "TOKEN"),
                  volumes=(f"{repo}/data:/data:ro", "ccache:/ccache", "/abs:/abs"))
    assert made["runArgs"][3:] == ["--network=host", "--ipc=host", "--privileged",
                                   "--device=/dev/ttyUSB0", "--gpus=device=0"]
    assert made["mounts"] == [
        "source=${localWorkspaceFolder}/data,target=/data,type=bind,readonly",
        "source=ccache,target=/ccache,type=volume", "source=/abs,target=/abs,type=bind",
        "source=/tmp/.X11-unix,target=/tmp/.X11-unix,type=bind"]
    env = made["containerEnv"]
    assert env["ROS_DOMAIN_ID"] == "7" and env["TOKEN"] == "${localEnv:TOKEN}"
    assert env["DISPLAY"] == "${localEnv:DISPLAY}" and env["QT_X11_NO_MITSHM"] == "1"
    assert "hostRequirements" not in made  # (an explicit --gpus value)


def test_gpus_auto_is_the_editors_check_and_none_is_none(tmp_path):
    repo = ros_repo(tmp_path)
    assert config(repo)["hostRequirements"] == {"gpu": "optional"}
    made = config(repo, gpus="none")
    assert "hostRequirements" not in made and "NVIDIA_DRIVER_CAPABILITIES" not in \
        made["containerEnv"]


def test_settings_from_the_environment_reach_the_editors_build(tmp_path):
    ros_repo(tmp_path)
    made = devcontainer.build_command(settings(tmp_path, ROS_DISTRO="noetic"))
    assert "ROS_DISTRO=noetic" in made and "BASE_IMAGE=base:1" in made
    assert not [a for a in made if a.startswith(("BUILD_CONTEXT=", "TARGET="))]
    secret = settings(tmp_path, GIT_HTTPS_PASSWORD="hunter2")
    assert not [a for a in devcontainer.build_command(secret) if "hunter2" in a]


@pytest.mark.parametrize("text", [
    '{\n  // a comment\n  "a": 1, /* more */ "b": [1, 2,],\n}\n',
    '{"a": 1, "b": [1, 2]}',
    '{"a": 1, "b": [1, 2], "s": "//not a comment, ]"}',
])
def test_jsonc_is_read(tmp_path, text):
    data = devcontainer.parse_jsonc(text, tmp_path / "x.json")
    assert data["a"] == 1 and data["b"] == [1, 2]


def test_invalid_jsonc_names_file_and_position(tmp_path):
    with pytest.raises(DevcontainerError, match=r"x.json is not valid JSON .*line 3 column"):
        devcontainer.parse_jsonc('{\n "a": 1\n "b": 2}', tmp_path / "x.json")
    with pytest.raises(DevcontainerError, match="holds list, not an object"):
        devcontainer.parse_jsonc("[]", tmp_path / "x.json")


def write_plan(repo: Path, ours: dict, force: bool = False) -> devcontainer.Plan:
    result = devcontainer.plan(settings(repo), ours, force=force)
    devcontainer.write(result)
    return result


def test_second_run_updates_ours_and_keeps_the_users_edits(tmp_path):
    repo = ros_repo(tmp_path)
    first = write_plan(repo, config(repo, network="host"))
    path = first.path
    data = json.loads(path.read_text())
    data["customizations"]["vscode"]["extensions"].remove("ms-python.python")
    data["customizations"]["vscode"]["extensions"].append("eamodio.gitlens")
    data["mounts"] = ["source=/data,target=/data,type=bind"]
    data["remoteEnv"] = {"MINE": "1"}
    data["containerEnv"]["ROS_DOMAIN_ID"] = "3"
    path.write_text("// my comment\n" + json.dumps(data, indent=2))
    assert devcontainer.plan(settings(repo), config(repo, network="host")).changed is False
    second = write_plan(repo, config(repo, network="none"))  # a setting changed
    again = json.loads(path.read_text())
    assert "--network=none" in again["runArgs"] and "--network=host" not in again["runArgs"]
    assert "--ipc=host" not in again["runArgs"]
    extensions = again["customizations"]["vscode"]["extensions"]
    assert "eamodio.gitlens" in extensions and "ms-python.python" not in extensions
    assert again["mounts"] == ["source=/data,target=/data,type=bind"]
    assert again["remoteEnv"] == {"MINE": "1"} and again["containerEnv"]["ROS_DOMAIN_ID"] == "3"
    assert "comments" in second.notes[0]
    assert devcontainer.plan(settings(repo), config(repo, network="none")).changed is False


def test_a_changed_value_of_ours_stays_the_users(tmp_path):
    repo = ros_repo(tmp_path)
    path = write_plan(repo, config(repo)).path
    data = json.loads(path.read_text())
    data["workspaceFolder"] = "/docker-ros/ws"
    path.write_text(json.dumps(data))
    merged = devcontainer.plan(settings(repo), config(repo)).content
    assert merged["workspaceFolder"] == "/docker-ros/ws"


def test_a_file_not_ours_is_never_overwritten_without_force(tmp_path):
    repo = ros_repo(tmp_path)
    path = repo / ".devcontainer" / "devcontainer.json"
    path.parent.mkdir()
    path.write_text('{"image": "mine", "forwardPorts": [3000]}')
    with pytest.raises(DevcontainerError, match=r"not written by docker-ros .* --force"):
        devcontainer.plan(settings(repo), config(repo))
    assert path.read_text() == '{"image": "mine", "forwardPorts": [3000]}'
    merged = write_plan(repo, config(repo), force=True).content
    assert merged["image"] == REF and merged["forwardPorts"] == [3000]
    assert devcontainer.plan(settings(repo), config(repo)).changed is False


def test_not_a_ros_repository(tmp_path):
    with pytest.raises(DevcontainerError, match="no package.xml and no .repos: it is not a ROS "
                       "repository; run it in the repository of your ROS packages"):
        config(tmp_path)
    (tmp_path / ".repos").write_text("repositories: {}\n")
    assert config(tmp_path)["image"] == REF


def test_no_dev_image_and_no_way_to_build_it(tmp_path):
    repo = ros_repo(tmp_path)
    unbuildable = load_settings(environ={"BUILD_CONTEXT": str(repo)}, project_dir=repo)
    with pytest.raises(DevcontainerError, match=r"the dev image robot:latest-dev is not built, "
                       r"and docker-ros cannot build it: missing required configuration: "
                       "BASE_IMAGE"):
        devcontainer.config_for(unbuildable, REF, ShellOptions(), user=USER, display="",
                                gpus="auto", image_present=False)
    made, notes = devcontainer.config_for(unbuildable, REF, ShellOptions(), user=USER,
                                          display="", gpus="auto", image_present=True)
    assert list(made["initializeCommand"]) == ["user"] and "used as it is" in notes[0]


def test_bad_json_changes_nothing(tmp_path):
    repo = ros_repo(tmp_path)
    path = repo / ".devcontainer" / "devcontainer.json"
    path.parent.mkdir()
    path.write_text('{"image": ')
    with pytest.raises(DevcontainerError, match="is not valid JSON"):
        devcontainer.plan(settings(repo), config(repo))
    assert path.read_text() == '{"image": '


def test_blacklisted_packages_are_named_for_colcon(tmp_path):
    repo = ros_repo(tmp_path)
    (repo / "docker").mkdir()
    (repo / "docker" / "blacklisted-packages.txt").write_text("# no\nunwanted\n")
    _made, notes = devcontainer.config_for(settings(repo), REF, ShellOptions(), user=USER,
                                           display="", gpus="auto", image_present=False)
    assert notes == ("colcon in the dev container builds the blacklisted packages too: give it "
                     "--packages-ignore unwanted",)


def test_run_dry_run_writes_nothing_and_check_says_whether_it_is_current(tmp_path, monkeypatch,
                                                                         capsys):
    repo = ros_repo(tmp_path)
    monkeypatch.setattr(devcontainer.engine, "inspect_image", lambda ref: None)
    monkeypatch.delenv("DISPLAY", raising=False)
    run = devcontainer.run
    options = ShellOptions()
    path = repo / ".devcontainer" / "devcontainer.json"
    assert run(settings(repo), options, x11="auto", gpus="auto", check=False, force=False,
               dry_run=True) == 0
    assert not path.exists() and json.loads(capsys.readouterr().out)["image"]
    assert run(settings(repo), options, x11="auto", gpus="auto", check=True, force=False,
               dry_run=False) == 1
    assert not path.exists() and "not up to date" in capsys.readouterr().out
    run(settings(repo), options, x11="auto", gpus="auto", check=False, force=False,
        dry_run=False)
    # (the host user's file, written when the folder is opened, stays out of git)
    assert (repo / ".devcontainer" / ".gitignore").read_text() == ".docker-ros-user.env\n"
    assert run(settings(repo), options, x11="auto", gpus="auto", check=True, force=False,
               dry_run=False) == 0
    assert run(settings(repo), options, x11="auto", gpus="none", check=True, force=False,
               dry_run=False) == 1
