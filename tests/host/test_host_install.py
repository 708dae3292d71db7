"""rosdep (offline rules), debs, pip, files: real rosdep, apt-get and pip on this root host."""

import json
import logging
import os
import shutil
import subprocess
from typing import Iterator

import pytest

from docker_ros.in_image.runtime.process import is_root
from docker_ros.in_image.runtime.workspace import StepError
from docker_ros.in_image.steps import blacklist, debs, files, pip, rosdep
from tests.rosfixtures import (
    make_package,
    make_wheel,
    rosdep_update,
    tree_snapshot,
    write_rosdep_rules,
)

pytestmark = pytest.mark.host
needs_root = pytest.mark.skipif(
    not is_root() or not shutil.which("apt-get"),
    reason="installs apt packages: needs root and apt-get",
)

RULES = {
    # toys no host package depends on (the install tests remove them first: toys_absent)
    "cmatrix_key": {"debian": ["cmatrix"], "ubuntu": ["cmatrix"]},
    "sl_key": {"debian": ["sl"], "ubuntu": ["sl"]},
    "six_key": {"debian": {"pip": {"packages": ["six"]}}, "ubuntu": {"pip": {"packages": ["six"]}}},
    "ubuntu_only": {"ubuntu": ["foo"]},
}


@pytest.fixture(scope="module")
def rosdep_db(tmp_path_factory):
    env = write_rosdep_rules(tmp_path_factory.mktemp("rosdep"), RULES)
    rosdep_update(env)
    return env


@pytest.fixture
def offline_rosdep(rosdep_db, environ, monkeypatch):
    environ(rosdep_db)
    # Debian's ROS 1 has no ROS_DISTRO: resolution must work with the OS rules alone.
    monkeypatch.delenv("ROS_DISTRO", raising=False)
    return rosdep_db


def dpkg_installed(name: str) -> bool:
    proc = subprocess.run(
        ["dpkg-query", "-W", "-f=${Status}", name], capture_output=True, text=True
    )
    return proc.stdout.strip() == "install ok installed"


def apt(*args: str) -> None:
    """apt-get, waiting for a lock another apt on this machine may hold."""
    subprocess.run(["apt-get", "-o", "DPkg::Lock::Timeout=300", "-y", "-q", *args], check=True,
                   capture_output=True, env={**os.environ, "DEBIAN_FRONTEND": "noninteractive"})


@pytest.fixture
def toys_absent() -> Iterator[None]:
    """cmatrix and sl not installed when the test starts (else an install step that installs
    nothing would pass); afterwards each is installed again, or removed, as it was before.
    `dpkg --remove` refuses (and so fails the test) rather than remove a package needing them;
    its refusal leaves them selected for removal: selected for install again."""
    names = ("cmatrix", "sl")
    before = {name for name in names if dpkg_installed(name)}
    if before:
        removed = subprocess.run(["dpkg", "--remove", *sorted(before)], capture_output=True,
                                 text=True)
        if removed.returncode:
            subprocess.run(["dpkg", "--set-selections"], check=True, capture_output=True,
                           input="".join(f"{name} install\n" for name in before), text=True)
            pytest.fail(f"cannot remove {', '.join(sorted(before))}: {removed.stderr.strip()}")
    assert not any(dpkg_installed(name) for name in names)
    try:
        yield
    finally:
        now = {name for name in names if dpkg_installed(name)}
        if before - now:
            apt("install", "--no-install-recommends", *sorted(before - now))
        if now - before:
            subprocess.run(["dpkg", "--remove", *sorted(now - before)], check=True,
                           capture_output=True)


@pytest.fixture
def ros_packages(project):
    make_package(
        project.repo / "app",
        "app",
        depends=["cmatrix_key", "lib"],
        test_depends=["sl_key"],
        build_type="ament_cmake",
    )
    make_package(project.repo / "lib", "lib", build_depends=["six_key"], build_type="ament_cmake")
    make_package(
        project.repo / "old", "old", exec_depends=["ubuntu_only"], build_type="ament_cmake"
    )
    (project.repo / "docker").mkdir()
    (project.repo / "docker" / "blacklisted-packages.txt").write_text("old\n")
    return project


def test_rosdep_collect_resolves_all_and_exec_sets(ros_packages, offline_rosdep):
    ws = ros_packages.ws
    before = tree_snapshot(ros_packages.repo)
    blacklist.main(ws, ros_packages.settings())

    rosdep.main(ws, ros_packages.settings(), phase="collect")

    assert ws.read_state("rosdep.json") == {
        "all": {"apt": ["cmatrix", "sl"], "pip": ["six"]},
        "exec": {"apt": ["cmatrix"], "pip": []},
    }
    first = (ws.state / "rosdep.json").read_bytes()
    rosdep.main(ws, ros_packages.settings(), phase="collect")
    assert (ws.state / "rosdep.json").read_bytes() == first  # deterministic
    assert tree_snapshot(ros_packages.repo) == before


def test_rosdep_unresolvable_key_names_key_and_package(project, offline_rosdep):
    make_package(
        project.repo / "a", "pkg_a", depends=["cmatrix_key", "no_such_key"],
        build_type="ament_cmake",
    )
    make_package(
        project.repo / "b",
        "pkg_b",
        exec_depends=["no_such_key", "ubuntu_only"],
        build_type="ament_cmake",
    )
    with pytest.raises(StepError) as err:
        rosdep.main(project.ws, project.settings(), phase="collect")
    message = err.value.message
    assert "'no_such_key' needed by pkg_a, pkg_b" in message
    assert "no rosdep rule for 'no_such_key'" in message
    assert "'ubuntu_only' needed by pkg_b" in message
    assert not (project.ws.state / "rosdep.json").exists()


@needs_root
def test_rosdep_apply_installs_from_state_only(
    ros_packages, offline_rosdep, venv_python, environ, toys_absent
):
    ws = ros_packages.ws
    rosdep.main(ws, ros_packages.settings(), phase="collect")
    # The install stage of an image has the state dir, not the sources.
    ros_packages.ws.target.unlink()
    environ({"DOCKER_ROS_PYTHON": str(venv_python)})

    rosdep.main(ws, ros_packages.settings(), phase="apply", dependency_types="all")

    assert dpkg_installed("cmatrix") and dpkg_installed("sl")
    subprocess.run([str(venv_python), "-c", "import six"], check=True)


def test_rosdep_dry_run_prints_exec_install(ros_packages, offline_rosdep, capsys):
    rosdep.main(ros_packages.ws, ros_packages.settings(), dry_run=True, dependency_types="exec")
    out = capsys.readouterr().out
    assert "apt-get install -y --no-install-recommends cmatrix\n" in out
    assert not [line for line in out.splitlines() if "sl" in line.split()]
    assert not ros_packages.ws.state.exists()


@needs_root
def test_debs_installs_each_entry(project, capsys, toys_absent):
    (project.repo / "docker").mkdir()
    (project.repo / "docker" / "additional-debs.txt").write_text(
        "# tools\nsl   \n\ncmatrix # matrix\n")
    debs.main(project.ws, project.settings())
    assert project.ws.read_state("debs.json") == {"packages": ["cmatrix", "sl"]}
    assert dpkg_installed("cmatrix") and dpkg_installed("sl")

    debs.main(project.ws, project.settings(), phase="apply", dry_run=True)
    assert "apt-get install -y --no-install-recommends cmatrix sl" in capsys.readouterr().out


def test_debs_recursive_and_missing(project, caplog):
    caplog.set_level(logging.INFO)
    debs.main(project.ws, project.settings(), phase="collect")
    assert project.ws.read_state("debs.json") == {"packages": []}
    assert "no docker/additional-debs.txt found" in caplog.text
    (project.repo / "sub").mkdir()
    (project.repo / "sub" / "additional-debs.txt").write_text("cmatrix\n")
    debs.main(project.ws, project.settings(enable_recursive_additional_debs="yes"), phase="collect")
    assert project.ws.read_state("debs.json") == {"packages": ["cmatrix"]}


def test_recursive_discovery_leaves_the_blacklisted_packages_files_out(project):
    """docker-ros removed the blacklisted packages before it looked for more list files and
    hooks: an imported package's additional-debs.txt and custom.sh went with it."""
    from docker_ros.in_image.steps import blacklist, custom
    from tests.rosfixtures import make_package

    for name in ("bad_pkg", "good_pkg"):
        make_package(project.ws.src / "upstream" / name, name)
        (project.ws.src / "upstream" / name / "additional-debs.txt").write_text(f"lib{name}\n")
        (project.ws.src / "upstream" / name / "custom.sh").write_text(f"echo {name}\n")
    (project.repo / "docker").mkdir()
    (project.repo / "docker" / "blacklisted-packages.txt").write_text("bad_pkg\n")
    settings = project.settings(enable_recursive_additional_debs="true",
                                enable_recursive_after_dependency_installation_script="true")
    blacklist.main(project.ws, settings)
    debs.main(project.ws, settings, phase="collect")
    custom.main(project.ws, settings, phase="collect")
    assert project.ws.read_state("debs.json") == {"packages": ["libgood_pkg"]}
    hooks = project.ws.read_state("custom.json")["hooks"]
    assert [hook["source"] for hook in hooks] == ["src/upstream/good_pkg/custom.sh"]


def test_pip_requirements_are_arguments_not_shell(
    project, venv_python, environ, monkeypatch, tmp_path
):
    (project.repo / "docker").mkdir()
    (project.repo / "docker" / "additional-pip-requirements.txt").write_text(
        '# pinned\nsix>=1.0\nsix>=1.0 # twice\ntomli; python_version >= "3"\n'
    )
    environ({"DOCKER_ROS_PYTHON": str(venv_python)})
    monkeypatch.chdir(tmp_path)

    pip.main(project.ws, project.settings())

    assert project.ws.read_state("pip.json") == {
        "requirements": ["six>=1.0", 'tomli; python_version >= "3"']
    }
    subprocess.run([str(venv_python), "-c", "import six, tomli"], check=True)
    # A shell would have redirected `six>=1.0` into a file named `=1.0`.
    assert not list(tmp_path.rglob("=1.0")) and not list(project.ws.root.rglob("=1.0"))


def test_pip_failure_names_the_file(project, venv_python, environ):
    (project.repo / "docker").mkdir()
    (project.repo / "docker" / "additional-pip-requirements.txt").write_text(
        "no-such-package-docker-ros-test==0.0.0\n"
    )
    environ({"DOCKER_ROS_PYTHON": str(venv_python)})
    with pytest.raises(StepError) as err:
        pip.main(project.ws, project.settings())
    assert "ADDITIONAL_PIP_FILE" in err.value.message
    assert "exit code" in err.value.message


def test_a_requirement_that_fails_to_build_is_named_with_its_error(project, venv_python,
                                                                   environ, tmp_path):
    """A package whose setup.py fails: pip ends with `hint: See above for details.`; the
    message names the requirement and the error the build printed (real pip)."""
    broken = tmp_path / "broken_dist"
    broken.mkdir()
    (broken / "setup.py").write_text("raise RuntimeError('needs libfoo-dev')\n")
    (project.repo / "docker").mkdir()
    (project.repo / "docker" / "additional-pip-requirements.txt").write_text(f"{broken}\n")
    environ({"DOCKER_ROS_PYTHON": str(venv_python)})
    with pytest.raises(StepError) as err:
        pip.main(project.ws, project.settings())
    assert str(broken) in err.value.message, err.value.message
    assert err.value.message.endswith("RuntimeError: needs libfoo-dev"), err.value.message


def test_an_invalid_requirement_is_named_by_its_line(project, venv_python, environ):
    """pip names a bad line by its number in our temporary file, gone after the step: the
    message shows the line itself (real pip: it refuses the file before any download)."""
    (project.repo / "docker").mkdir()
    (project.repo / "docker" / "additional-pip-requirements.txt").write_text(
        "six\nthis is not a requirement\n")
    environ({"DOCKER_ROS_PYTHON": str(venv_python)})
    with pytest.raises(StepError) as err:
        pip.main(project.ws, project.settings())
    assert "(from the requirement line 'this is not a requirement')" in err.value.message
    assert "from line" not in err.value.message


def test_files_stages_and_copies(project, tmp_path):
    src = project.repo / "docker" / "additional-files"
    (src / "etc").mkdir(parents=True)
    (src / "etc" / "app.conf").write_text("x=1\n")
    (src / "link").symlink_to("etc/app.conf")
    before = tree_snapshot(project.repo)
    dest = tmp_path / "dest"

    files.main(project.ws, project.settings(), phase="collect")
    src.joinpath("etc", "app.conf").write_text("changed after collect\n")
    files.main(project.ws, project.settings(), phase="apply", destination=str(dest))

    assert (dest / "etc" / "app.conf").read_text() == "x=1\n"
    assert (dest / "link").is_symlink()
    files.main(project.ws, project.settings(), phase="apply", destination=str(dest))  # idempotent
    src.joinpath("etc", "app.conf").write_text("x=1\n")
    assert tree_snapshot(project.repo) == before


def test_files_missing_dir_and_dry_run(project, tmp_path, caplog, capsys):
    caplog.set_level(logging.INFO)
    files.main(project.ws, project.settings(), destination=str(tmp_path / "dest"))
    assert "nothing to copy" in caplog.text
    assert (project.ws.state / "additional-files").is_dir()
    assert not (tmp_path / "dest").exists()

    (project.repo / "docker" / "additional-files").mkdir(parents=True)
    (project.repo / "docker" / "additional-files" / "f").write_text("f")
    snapshot = tree_snapshot(project.ws.root)
    files.main(project.ws, project.settings(), destination=str(tmp_path / "d2"), dry_run=True)
    out = capsys.readouterr().out
    assert f"[dry-run] files: copy {project.repo}" not in out  # shown through src/target
    assert f"-> {tmp_path / 'd2'}/" in out
    assert tree_snapshot(project.ws.root) == snapshot
    assert not (tmp_path / "d2").exists()


def test_state_json_is_sorted_and_stable(project):
    (project.repo / "docker").mkdir()
    (project.repo / "docker" / "additional-debs.txt").write_text("zsh\nawk\n")
    debs.main(project.ws, project.settings(), phase="collect")
    text = (project.ws.state / "debs.json").read_text()
    assert json.loads(text) == {"packages": ["awk", "zsh"]}
    assert text == json.dumps({"packages": ["awk", "zsh"]}, indent=2, sort_keys=True) + "\n"


def test_pip_reads_requirement_files_as_pip_does(
    project, venv_python, environ, monkeypatch, tmp_path
):
    """Continuations, comments, nested -r/-c files relative to the file naming them (the step
    runs elsewhere), ${VARIABLES} expanded by pip, never written into the plan: a real pip
    install from local wheels."""
    wheels = tmp_path / "wheels"
    wheels.mkdir()
    for name, version in [("drt_alpha", "1.0"), ("drt_beta", "2.0"), ("drt_gamma", "1.0"),
                          ("drt_gamma", "2.0")]:
        make_wheel(wheels, name, version)
    docker = project.repo / "docker"
    (docker / "nested").mkdir(parents=True)
    (docker / "additional-pip-requirements.txt").write_text(
        "--no-index\n--find-links ${DRT_WHEELS}  # expanded by pip\n-r nested/more.txt\n"
        "drt_alpha \\\n  >=1.0\n")
    (docker / "nested" / "more.txt").write_text("drt_beta==2.0 # pinned\ndrt_gamma\n"
                                                "-c pins.txt\n")
    (docker / "nested" / "pins.txt").write_text("drt_gamma<2\n")
    environ({"DOCKER_ROS_PYTHON": str(venv_python), "DRT_WHEELS": str(wheels)})
    monkeypatch.chdir(tmp_path)  # not the folder of any requirement file

    pip.main(project.ws, project.settings())

    assert project.ws.read_state("pip.json") == {
        "requirements": ["--no-index", "--find-links ${DRT_WHEELS}", "drt_beta==2.0",
                         "drt_gamma", "drt_alpha   >=1.0"],
        "constraints": ["drt_gamma<2"],
    }
    versions = subprocess.run(
        [str(venv_python), "-c", "import drt_alpha, drt_beta, drt_gamma; "
         "print(drt_alpha.VERSION, drt_beta.VERSION, drt_gamma.VERSION)"],
        capture_output=True, text=True, check=True).stdout.split()
    assert versions == ["1.0", "2.0", "1.0"]  # gamma held below 2 by the nested constraint


def test_pip_names_a_missing_nested_file(project, tmp_path, monkeypatch):
    (project.repo / "docker").mkdir()
    (project.repo / "docker" / "additional-pip-requirements.txt").write_text("-r more.txt\n")
    (tmp_path / "more.txt").write_text("six\n")  # in the working directory: not the one
    monkeypatch.chdir(tmp_path)
    with pytest.raises(StepError) as err:
        pip.main(project.ws, project.settings(), phase="collect")
    assert "additional-pip-requirements.txt:1: `-r more.txt`: " in err.value.message
    assert "docker/more.txt not found" in err.value.message
