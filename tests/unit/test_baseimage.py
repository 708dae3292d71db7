"""Command construction of the debootstrap base images (the builds themselves: tests/docker)."""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

import pytest

from docker_ros.host import baseimage
from docker_ros.in_image.runtime.workspace import StepError


def test_every_flavor_is_a_dockerfile_stage() -> None:
    stages = re.findall(r"^FROM \S+ AS (\S+)$", baseimage.DOCKERFILE.read_text(), re.MULTILINE)
    assert {spec.stage for spec in baseimage.FLAVORS.values()} <= set(stages)


def test_build_argv_passes_the_ca_bundle_as_a_secret_only() -> None:
    spec = baseimage.FLAVORS["ros1"]
    ca = Path("/etc/ssl/certs/ca-certificates.crt")
    argv = baseimage.build_argv(spec, "t:1", "rootfs:x", "arm64", ca, Path("/ctx"))
    assert argv[:4] == ["docker", "buildx", "build", "--load"]
    assert argv[argv.index("--platform") + 1] == "linux/arm64"
    assert argv[argv.index("--target") + 1] == "ros1"
    assert argv[argv.index("--secret") + 1] == f"id=EXTRA_CA_CERTS,src={ca}"
    assert [arg for arg in argv if str(ca) in arg] == [f"id=EXTRA_CA_CERTS,src={ca}"]
    assert argv[-1] == "/ctx"
    without = baseimage.build_argv(spec, "t:1", "rootfs:x", "amd64", None, Path("/ctx"))
    assert "--secret" not in without


def test_build_argv_reaches_the_engine_and_network_it_is_given() -> None:
    """`inv example` under a docker-context BUILDER bootstraps its base in that engine."""
    spec = baseimage.FLAVORS["ros1"]
    argv = baseimage.build_argv(spec, "t:1", "rootfs:x", "amd64", None, Path("/ctx"),
                                ["docker", "--context", "e26"], "host")
    assert argv[:5] == ["docker", "--context", "e26", "buildx", "build"]
    assert argv[argv.index("--network") + 1] == "host"
    assert "--network" not in baseimage.build_argv(spec, "t:1", "rootfs:x", "amd64", None,
                                                   Path("/ctx"))


def test_debs_are_one_build_arg() -> None:
    spec = baseimage.FLAVORS["ros2"]
    argv = baseimage.build_argv(spec, "t:1", "rootfs:x", "amd64", None, Path("/ctx"))
    debs = [a for a in argv if a.startswith("DEBS=")]
    assert debs == ["DEBS=" + " ".join(spec.debs)]
    assert "ament-cmake" in spec.debs and "tini" in spec.debs


def test_the_recipe_label_changes_with_the_package_list() -> None:
    spec = baseimage.FLAVORS["ros1"]
    argv = baseimage.build_argv(spec, "t:1", "rootfs:x", "amd64", None, Path("/ctx"))
    assert argv[argv.index("--label") + 1] == f"{baseimage.RECIPE_LABEL}={baseimage.recipe(spec)}"
    more = baseimage.Flavor(spec.name, spec.suite, spec.debs + ("htop",))
    assert baseimage.recipe(more) != baseimage.recipe(spec)
    assert baseimage.recipe(spec) != baseimage.recipe(baseimage.FLAVORS["ros2"])
    assert "openssh-client" in spec.debs  # git over ssh in the clone step


def test_debootstrap_argv_is_minbase_for_the_platform() -> None:
    argv = baseimage.debootstrap_argv("bookworm", Path("/tmp/r"), "http://m/debian", "arm64")
    assert argv == [
        "debootstrap", "--variant=minbase", "--arch=arm64", "bookworm", "/tmp/r", "http://m/debian",
    ]  # fmt: skip


def test_ubuntu_is_debootstrapped_with_universe_and_checked_against_its_key() -> None:
    argv = baseimage.debootstrap_argv("jammy", Path("/tmp/r"), "http://m/ubuntu", "amd64",
                                      components=("main", "universe"), keyring=Path("/k.gpg"))
    assert argv == [
        "debootstrap", "--variant=minbase", "--arch=amd64", "--components=main,universe",
        "--keyring=/k.gpg", "jammy", "/tmp/r", "http://m/ubuntu",
    ]  # fmt: skip


def test_each_distribution_and_architecture_has_its_mirror() -> None:
    assert baseimage.default_mirror("debian", "arm64") == "http://deb.debian.org/debian"
    assert baseimage.default_mirror("ubuntu", "amd64") == "http://archive.ubuntu.com/ubuntu"
    # Ubuntu's archive has no arm64: its ports mirror has
    assert baseimage.default_mirror("ubuntu", "arm64") == "http://ports.ubuntu.com/ubuntu-ports"


def test_the_shipped_key_is_the_ubuntu_archive_signing_key() -> None:
    """The OpenPGP v4 fingerprint (RFC 4880, 12.2) of the dearmored key: SHA-1 over 0x99, the
    two-byte length and the public-key packet's body. A wrong or damaged key fails here, not
    in a debootstrap that then trusts nothing."""
    key = baseimage.dearmor(baseimage.UBUNTU_KEY.read_text())
    assert key[0] == 0x99  # an old-format public-key packet with a two-byte length
    length = int.from_bytes(key[1:3], "big")
    fingerprint = hashlib.sha1(b"\x99" + key[1:3] + key[3:3 + length]).hexdigest().upper()
    assert fingerprint == "F6ECB3762474EDA9D21B7022871920D1991BC93C"


def test_ubuntu_flavor_names_its_stage_and_pypi_tools() -> None:
    spec = baseimage.FLAVORS["ros1-ubuntu"]
    assert baseimage.default_tag("ros1-ubuntu") == "docker-ros/ros1:jammy"
    argv = baseimage.build_argv(spec, "t:1", "rootfs:x", "amd64", None, Path("/ctx"))
    assert argv[argv.index("--target") + 1] == "ros1-ubuntu"
    pip = [a for a in argv if a.startswith("PIP_PACKAGES=")]
    assert pip == ["PIP_PACKAGES=colcon-common-extensions==0.3.0 vcstool==0.3.0"]
    assert "colcon" not in spec.debs and "vcstool" not in spec.debs  # not packaged by Ubuntu
    assert "PIP_PACKAGES=" not in " ".join(baseimage.build_argv(
        baseimage.FLAVORS["ros1"], "t:1", "rootfs:x", "amd64", None, Path("/ctx")))


def test_unknown_flavor_and_missing_ca_bundle_are_clear_errors(tmp_path: Path) -> None:
    with pytest.raises(StepError, match="unknown flavor 'ros3'; choose one of ros1, ros2"):
        baseimage.bootstrap("ros3", tag="x:y")
    with pytest.raises(StepError, match="CA bundle .* not found"):
        baseimage.bootstrap("ros1", tag="x:y", ca_bundle=tmp_path / "nope.pem")


def test_mounts_below_finds_nothing_under_a_fresh_directory(tmp_path: Path) -> None:
    assert baseimage.mounts_below(tmp_path) == []
    assert "/proc" in baseimage.mounts_below(Path("/proc"))


def test_existing_base_image_is_reused_only_for_the_same_recipe_and_architecture() -> None:
    same = baseimage.stale_reason("r1", "amd64", recipe="r1", platform="amd64")
    assert same == ""
    other_arch = baseimage.stale_reason("r1", "amd64", recipe="r1", platform="arm64")
    assert "amd64, not arm64" in other_arch
    assert "recipe" in baseimage.stale_reason("r0", "arm64", recipe="r1", platform="arm64")
    assert "unknown" in baseimage.stale_reason(None, None, recipe="r1", platform="amd64")


def test_an_architecture_other_than_the_hosts_gets_a_tag_of_its_own() -> None:
    """Bootstrapping arm64 never replaces the amd64 image of the same name (and back)."""
    assert baseimage.platform_tag("docker-ros/ros1:bookworm", "amd64", "amd64") == (
        "docker-ros/ros1:bookworm")
    assert baseimage.platform_tag("docker-ros/ros1:bookworm", "arm64", "amd64") == (
        "docker-ros/ros1:bookworm-arm64")
    assert baseimage.platform_tag("docker-ros/ros1:bookworm", "amd64", "arm64") == (
        "docker-ros/ros1:bookworm-amd64")
    assert baseimage.arch_ref("127.0.0.1:5000/ros", "arm64") == "127.0.0.1:5000/ros:latest-arm64"
