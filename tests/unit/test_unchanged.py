"""A rebuild with nothing changed stands on the record of the last build (host/unchanged.py):
which builds may, what the inputs hold, and when the record says up to date. (The build that
skips BuildKit and the one that runs it after a change: tests/docker/test_image_build.py.)"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from docker_ros.core.settings import Settings
from docker_ros.host import unchanged

SPEC = {"context": "/repo", "dockerfile": "/tmp/docker-ros-build-abc/Dockerfile",
        "target": "run", "tags": ["x:1"], "args": {"BASE_IMAGE": "b:1"},
        "secret": ["id=EXTRA_CA_CERTS,src=/tmp/docker-ros-build-abc/ca.pem"]}


@pytest.mark.parametrize("change, applies", [
    ({}, True),
    ({"cache_to": "r/x:cache"}, False),  # the build exports a cache: it must run
    ({"no_cache": True}, False),
    ({"build_state_from": "r/x:state"}, False),
])
def test_only_a_plain_local_build_stands_on_its_record(change: dict, applies: bool) -> None:
    settings = dataclasses.replace(Settings(), **change)
    targets = {"dev": "x:1-dev", "run": "x:1"}
    assert unchanged.applies(settings, targets, push=False, output="",
                             own_buildkit=False) is applies
    plain = Settings()
    assert not unchanged.applies(plain, targets, push=True, output="", own_buildkit=False)
    assert not unchanged.applies(plain, targets, push=False, output="type=tar",
                                 own_buildkit=False)
    assert not unchanged.applies(plain, targets, push=False, output="", own_buildkit=True)
    assert not unchanged.applies(plain, {"test-results": "t"}, push=False, output="",
                                 own_buildkit=False)


def test_in_a_ci_job_cache_exports_seeds_and_the_build_state_stand_on_the_jobs_record(
    tmp_path: Path
) -> None:
    """`docker-ros ci` runs build, test, slim, then push: push's build of the same inputs
    stands on the job's record (the images the job tested are pushed, not a rebuild of them),
    which is kept beside the job's record, not in the user's cache (an earlier job's is never
    read)."""
    ci = dataclasses.replace(Settings(), cache_to="r/x:cache", build_state_from=("r/x:s",))
    targets = {"dev": "x:1-dev", "run": "x:1", "build-state": "x:1-build-state-amd64"}
    assert not unchanged.applies(ci, targets, push=False, output="", own_buildkit=False)
    assert unchanged.applies(ci, targets, push=False, output="", own_buildkit=False,
                             in_job=True)
    assert not unchanged.applies(dataclasses.replace(ci, no_cache=True), targets, push=False,
                                 output="", own_buildkit=False, in_job=True)
    assert not unchanged.applies(ci, targets, push=False, output="", own_buildkit=True,
                                 in_job=True)
    assert not unchanged.applies(ci, {"test-results": "t"}, push=False, output="",
                                 own_buildkit=False, in_job=True)
    job = {"XDG_CACHE_HOME": str(tmp_path / "cache"),
           "DOCKER_ROS_JOB_RECORD": str(tmp_path / "job" / "record.jsonl")}
    assert unchanged.in_job(job) and not unchanged.in_job({})
    path = unchanged.record_path("unix:///a.sock", tmp_path / "repo", "amd64", job)
    assert path.parent == tmp_path / "job" / "builds"


def test_a_targets_inputs_leave_out_the_temporary_folder_and_follow_everything_else() -> None:
    shared = unchanged.shared_inputs(b"FROM b", "ctx", {"base": "sha256:1"})
    digest = unchanged.target_inputs(SPEC, "/tmp/docker-ros-build-abc", shared)
    moved = {**SPEC, "dockerfile": "/tmp/docker-ros-build-xyz/Dockerfile",
             "secret": ["id=EXTRA_CA_CERTS,src=/tmp/docker-ros-build-xyz/ca.pem"]}
    assert unchanged.target_inputs(moved, "/tmp/docker-ros-build-xyz", shared) == digest
    argument = {**SPEC, "args": {"BASE_IMAGE": "b:2"}}
    assert unchanged.target_inputs(argument, "/tmp/docker-ros-build-abc", shared) != digest
    for other in (unchanged.shared_inputs(b"FROM c", "ctx", {"base": "sha256:1"}),
                  unchanged.shared_inputs(b"FROM b", "edited", {"base": "sha256:1"}),
                  unchanged.shared_inputs(b"FROM b", "ctx", {"base": "sha256:2"})):
        assert unchanged.target_inputs(SPEC, "/tmp/docker-ros-build-abc", other) != digest


def test_up_to_date_needs_the_same_inputs_and_the_same_image_for_every_tag() -> None:
    record = {"images": {"x:1": {"inputs": "a", "id": "sha256:1"},
                         "x:1-dev": {"inputs": "b", "id": "sha256:2"}}}
    both = {"x:1": "a", "x:1-dev": "b"}
    ids = {"x:1": "sha256:1", "x:1-dev": "sha256:2"}
    assert unchanged.up_to_date(record, both, ids)
    assert unchanged.up_to_date(record, {"x:1": "a"}, ids)  # run alone, after dev and run
    assert not unchanged.up_to_date(record, {**both, "x:1": "c"}, ids)  # an input changed
    assert not unchanged.up_to_date(record, both, {**ids, "x:1": "sha256:9"})  # retagged
    assert not unchanged.up_to_date(record, both, {**ids, "x:1": None})  # removed
    assert not unchanged.up_to_date(record, {"x:2": "a"}, {"x:2": "sha256:1"})  # never built
    assert not unchanged.up_to_date({}, both, ids)
    assert not unchanged.up_to_date(record, {}, ids)


def test_the_record_is_per_engine_repository_and_platform_in_the_users_cache(
    tmp_path: Path
) -> None:
    environ = {"XDG_CACHE_HOME": str(tmp_path / "cache")}
    path = unchanged.record_path("unix:///a.sock", tmp_path / "repo", "amd64", environ)
    assert path.parent == tmp_path / "cache" / "docker-ros" / "builds"
    others = {unchanged.record_path("unix:///b.sock", tmp_path / "repo", "amd64", environ),
              unchanged.record_path("unix:///a.sock", tmp_path / "other", "amd64", environ),
              unchanged.record_path("unix:///a.sock", tmp_path / "repo", "arm64", environ)}
    assert path not in others and len(others) == 3


def test_a_record_written_keeps_the_other_tags_and_a_broken_one_reads_as_none(
    tmp_path: Path
) -> None:
    path = tmp_path / "builds" / "r.json"
    assert unchanged.read(path) == {}
    unchanged.write(path, {"x:1-dev": {"inputs": "b", "id": "sha256:2", "digest": ""}})
    unchanged.write(path, {"x:1": {"inputs": "a", "id": "sha256:1", "digest": ""}})
    assert set(unchanged.read(path)["images"]) == {"x:1", "x:1-dev"}
    assert [p.name for p in path.parent.iterdir()] == ["r.json"]  # (no temporary file left)
    path.write_text("{not json")
    assert unchanged.read(path) == {}
