"""The seed of a build's colcon step (host/buildstate.py) and the order of the builds."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Dict

from docker_ros.host import buildcontext, buildplan, buildstate
from docker_ros.host.buildstate import EMPTY, INPUTS_LABEL, SEED_LABEL, choose_seed

PULLED = "reg:5000/g/p:latest-build-state-amd64"
DIGEST = "sha256:" + "ab" * 32
OWN = f"reg:5000/g/p@{DIGEST}"


def attrs(labels: Dict[str, str], architecture: str = "amd64") -> Dict[str, Any]:
    """An image inspect of the pulled state."""
    return {"Architecture": architecture, "Config": {"Labels": labels},
            "RepoDigests": ["reg:5000/g/other@sha256:" + "cd" * 32, OWN]}


def test_a_state_of_the_same_inputs_seeds_as_its_build_did_and_stands_as_this_builds() -> None:
    same = attrs({INPUTS_LABEL: "f1", SEED_LABEL: EMPTY})
    seed = choose_seed(PULLED, same, "amd64", "f1", registry_cache=True)
    assert (seed.ref, seed.recorded, seed.reuse) == ("", EMPTY, PULLED)
    assert seed.build_args() == {}
    assert "seeding as that build was (empty)" in seed.why
    earlier = f"reg:5000/g/p@sha256:{'12' * 32}"
    seed = choose_seed(PULLED, attrs({INPUTS_LABEL: "f1", SEED_LABEL: earlier}), "amd64", "f1",
                       registry_cache=True)
    assert (seed.ref, seed.recorded, seed.reuse) == (earlier, earlier, PULLED)
    assert seed.build_args() == {buildstate.SEED_ARG: earlier}


def test_other_inputs_or_no_registry_cache_build_over_the_pulled_state() -> None:
    """The state is the seed, and the new state records it by digest in its repository."""
    same = attrs({INPUTS_LABEL: "f1", SEED_LABEL: EMPTY})
    for seed in (choose_seed(PULLED, same, "amd64", "f2", registry_cache=True),
                 choose_seed(PULLED, same, "amd64", "f1", registry_cache=False),
                 choose_seed(PULLED, attrs({}), "amd64", "f1", registry_cache=True)):
        assert (seed.ref, seed.recorded, seed.reuse) == (PULLED, OWN, "")
    assert "its inputs differ from this build's" in choose_seed(
        PULLED, same, "amd64", "f2", registry_cache=True).why


def test_a_recorded_seed_outside_the_states_repository_is_never_used() -> None:
    for recorded in ("evil.example/x@sha256:" + "ab" * 32, "reg:5000/g/p:latest", "",
                     "reg:5000/g/p@sha256:short"):
        seed = choose_seed(PULLED, attrs({INPUTS_LABEL: "f1", SEED_LABEL: recorded}), "amd64",
                           "f1", registry_cache=True)
        assert (seed.ref, seed.reuse) == (PULLED, ""), recorded


def test_a_state_of_another_architecture_is_not_used() -> None:
    seed = choose_seed(PULLED, attrs({INPUTS_LABEL: "f1", SEED_LABEL: EMPTY}, "arm64"),
                       "amd64", "f1", registry_cache=True)
    assert (seed.ref, seed.recorded, seed.reuse) == ("", EMPTY, "")
    assert seed.why == f"{PULLED} is a build state for arm64, not amd64: not used"


def test_an_unknown_digest_is_recorded_as_unknown_never_as_the_empty_seed() -> None:
    """Recording `none` for a build over a state would make the next build's seed another."""
    seed = choose_seed(PULLED, {"Architecture": "amd64"}, "amd64", "f1", registry_cache=True)
    assert (seed.ref, seed.recorded) == (PULLED, "")


def test_the_fingerprint_follows_files_modes_and_parts_but_not_the_seed(tmp_path: Path) -> None:
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "a.cpp").write_text("int a;\n")
    parts = {"CMAKE_ARGS": "", buildstate.SEED_ARG: "reg/p:x", "platform": "amd64"}

    def fingerprint(**changed: str) -> str:
        return buildstate.inputs_fingerprint(tmp_path, {**parts, **changed}, buildcontext.left_out)

    first = fingerprint()
    assert fingerprint(**{buildstate.SEED_ARG: "y"}) == first
    assert fingerprint(platform="arm64") != first
    assert fingerprint(CMAKE_ARGS="-DX=1") != first
    (tmp_path / ".env").write_text("GIT_HTTPS_PASSWORD=x\n")  # never sent
    (tmp_path / buildcontext.SCRATCH_FOLDER).mkdir()
    (tmp_path / buildcontext.SCRATCH_FOLDER / "copy.cpp").write_text("int b;\n")
    (tmp_path / ".git").mkdir()  # never sent either (a commit or fetch changes no build)
    (tmp_path / ".git" / "config").write_text("[remote]\n")
    (tmp_path / "pkg" / ".gitlab-ci-local-variables.yml").write_text("X: y\n")
    assert fingerprint() == first
    (tmp_path / "pkg" / "b.cpp").write_text("int b;\n")
    with_b = fingerprint()
    assert with_b != first
    (tmp_path / "pkg" / "a.cpp").chmod(0o755)
    assert fingerprint() != with_b
    (tmp_path / "pkg" / "a.cpp").chmod(0o644)
    assert fingerprint() == with_b
    (tmp_path / "pkg" / "a.cpp").write_text("int a = 1;\n")
    assert fingerprint() != with_b


def test_with_a_registry_cache_run_and_its_build_state_are_built_before_dev() -> None:
    assert buildplan.build_order(["dev", "run", "build-state"], registry_cache=True) == [
        "run", "build-state", "dev"]
    assert buildplan.build_order(["dev", "run", "build-state"], registry_cache=False) == [
        "dev", "run", "build-state"]
    assert buildplan.build_order(["dev"], registry_cache=True) == ["dev"]
    assert buildplan.build_order(["test-results"], registry_cache=True) == ["test-results"]


def test_repository_of_a_reference() -> None:
    assert buildstate.repository("reg:5000/g/p:tag") == "reg:5000/g/p"
    assert buildstate.repository(OWN) == "reg:5000/g/p"
    assert buildstate.repository("reg:5000/g/p") == "reg:5000/g/p"
    assert buildstate.repo_digest(PULLED, attrs({})) == OWN
