"""What a build and a push report (issue 46): the digests in buildx's metadata file, the cached
steps of its log, the pushed digests as CI outputs, the GitHub job summary."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from docker_ros.core.loading import load_settings
from docker_ros.host import buildlog, engine, jobsummary
from docker_ros.host.buildmeta import image_digests, read_metadata
from docker_ros.host.push import plan_outputs, run_commands

DIGEST = "sha256:" + "a" * 64


def settings(**environ):
    return load_settings(environ={"BASE_IMAGE": "base:1", "COMMAND": "run me", **environ},
                         project_dir=Path("/tmp/robot"))


def test_digests_come_from_buildx_s_metadata_file(tmp_path):
    # as buildx 0.13 writes them on Engine 20.10 (classic store: the image ID)
    build = {"buildx.build.ref": "default/default/x", "containerimage.digest": DIGEST}
    assert image_digests(build, ["run"]) == {"run": DIGEST}
    bake = {"dev": {"containerimage.config.digest": "sha256:c"},
            "run": {"containerimage.digest": DIGEST, "containerimage.config.digest": "sha256:d"}}
    assert image_digests(bake, ["dev", "run"]) == {"dev": "sha256:c", "run": DIGEST}
    assert image_digests({}, ["dev", "run"]) == {}
    assert image_digests({"buildx.build.ref": "x"}, ["run"]) == {}
    (tmp_path / "m.json").write_text(json.dumps(bake))
    assert read_metadata(tmp_path / "m.json") == bake
    (tmp_path / "m.json").write_text("not json")
    assert read_metadata(tmp_path / "m.json") == {}
    assert read_metadata(tmp_path / "none.json") == {}


def test_cached_steps_are_counted_from_the_plain_log():
    log = [
        "#1 [internal] load build definition from Dockerfile",
        "#5 [base 1/3] FROM docker.io/library/debian:12",
        "#6 [base 2/3] RUN apt-get update",
        "#6 CACHED",
        "#7 [run dependencies-run 1/2] COPY --from=tools / /docker-ros/lib",
        "#7 CANCELED",
        "#8 [run build 1/1] RUN python3 -m docker_ros.in_image.steps colcon",
        "#8 0.512 Starting >>> colcon",
        "#8 DONE 3.1s",
    ]
    assert buildlog.cached_steps(log) == (2, 3)
    assert buildlog.cached_steps([]) == (0, 0)


def test_pushes_give_their_digests_and_the_action_outputs_them(monkeypatch):
    s = settings(IMAGE="reg:5000/team/robot:1", TARGET="dev,run")
    monkeypatch.setattr(engine, "push", lambda ref, auth: DIGEST if ref.endswith(":1") else "")
    pushed = run_commands(s, [["docker", "push", "reg:5000/team/robot:1-dev"],
                              ["docker", "push", "reg:5000/team/robot:1"]],
                          dry_run=False, label="push")
    assert pushed == {"reg:5000/team/robot:1-dev": "", "reg:5000/team/robot:1": DIGEST}
    outputs = plan_outputs(s, ["dev", "run"], pushed)
    assert outputs == {
        "images": "reg:5000/team/robot:1-dev,reg:5000/team/robot:1",
        "dev-image": "reg:5000/team/robot:1-dev",
        "image": "reg:5000/team/robot:1", "digest": DIGEST,
        "digests": json.dumps({"reg:5000/team/robot:1": DIGEST}),
    }
    assert "\n" not in outputs["digests"]  # (one `key=value` line of GITHUB_OUTPUT)
    assert plan_outputs(s, ["run"], {"reg:5000/team/robot:1": ""}) == {
        "images": "reg:5000/team/robot:1", "image": "reg:5000/team/robot:1"}


def test_the_pushed_build_state_s_digest_is_an_output_of_its_own():
    """The build state (BUILD_STATE_FROM, one per architecture): `build-state-digest`, not in
    `images` and `digests` (the images of the user's)."""
    s = settings(IMAGE="reg:5000/team/robot:1", TARGET="run",
                 BUILD_STATE_FROM="reg:5000/team/robot:1-build-state")
    state = "reg:5000/team/robot:1-build-state-amd64"
    pushed = {"reg:5000/team/robot:1": DIGEST, state: "sha256:" + "b" * 64}
    assert plan_outputs(s, ["run", "build-state"], pushed) == {
        "images": "reg:5000/team/robot:1",
        "image": "reg:5000/team/robot:1", "digest": DIGEST,
        "build-state-image": state, "build-state-digest": "sha256:" + "b" * 64,
        "digests": json.dumps({"reg:5000/team/robot:1": DIGEST}),
    }


def test_engine_push_returns_the_digest_the_engine_names(monkeypatch):
    class Images:
        def push(self, repository, **kw):
            yield {"status": "Pushing"}
            yield {"status": "1: digest: ...", "aux": {"Tag": "1", "Digest": DIGEST, "Size": 9}}
            yield {"status": "done"}

    class Client:
        images = Images()

    monkeypatch.setattr(engine, "client", lambda: Client())
    assert engine.push("reg:5000/x:1") == DIGEST


def test_an_engine_on_the_containerd_store_names_the_digest_in_the_status_only():
    # Engine 26's push stream, as it came (2026-11-29): no `aux` event; the Action's
    # `digests` output was missing on a runner engine with the containerd image store
    pushed = {"status": f"1: digest: {DIGEST} size: 855"}
    assert engine.pushed_digest(pushed) == DIGEST
    assert engine.pushed_digest({"status": "Pushed", "id": "0fa16e429479"}) == ""
    assert engine.pushed_digest({"aux": {"Tag": "1", "Digest": DIGEST, "Size": 9}}) == DIGEST


ENTRIES = [
    {"kind": "image", "target": "dev", "ref": "reg/robot:1-dev", "platform": "amd64",
     "seconds": 40.54, "size": 812_000_000, "cached": [12, 14], "digest": DIGEST},
    {"kind": "image", "target": "run", "ref": "reg/robot:1", "platform": "amd64",
     "seconds": 40.54, "size": 400_000_000, "cached": [12, 14]},
    {"kind": "image", "target": "slim", "ref": "reg/robot:1-slim", "platform": "amd64",
     "seconds": 35.0, "size": 90_000_000, "run_size": 400_000_000, "reused": False},
    {"kind": "pushed", "name": "reg/robot:1", "digest": DIGEST},
    {"kind": "pushed", "name": "reg/robot:1-slim", "digest": ""},
]


def test_the_job_s_record_gives_the_pushed_names_with_their_digests():
    """What `ci` and `manifest` read back after their tasks (each a process of its own)
    pushed: the dotenv report's digests."""
    assert jobsummary.pushed_digests(ENTRIES) == {"reg/robot:1": DIGEST, "reg/robot:1-slim": ""}
    environ = {}
    with jobsummary.job_record(environ) as path:
        jobsummary.record({"kind": "pushed", "name": "reg/robot:1-amd64", "digest": DIGEST},
                          environ)
        jobsummary.record({"kind": "image", "ref": "reg/robot:1-amd64"}, environ)
        assert jobsummary.pushed_digests(jobsummary.read_record(path)) == {
            "reg/robot:1-amd64": DIGEST}


def test_the_job_summary_is_a_table_of_the_images_and_one_of_the_digests():
    assert jobsummary.render_summary(ENTRIES) == "\n".join([
        "### docker-ros",
        "",
        "| image | platform | size | build time | cached steps | slim ratio |",
        "|---|---|---|---|---|---|",
        "| `reg/robot:1-dev` | amd64 | 812 MB | 40.5 s | 12/14 |  |",
        "| `reg/robot:1` | amd64 | 400 MB | 40.5 s | 12/14 |  |",
        "| `reg/robot:1-slim` | amd64 | 90 MB | 35.0 s (traced, checked) |  | 4.4x |",
        "",
        "| pushed | digest |",
        "|---|---|",
        f"| `reg/robot:1` | `{DIGEST}` |",
        "| `reg/robot:1-slim` | - |",
        "",
    ])
    reused = {**ENTRIES[2], "reused": True}
    assert "| 35.0 s (up to date) |" in jobsummary.render_summary([reused])
    assert jobsummary.render_summary([]) == ""


def test_a_job_s_tasks_record_and_the_job_writes_the_summary_once(tmp_path):
    summary = tmp_path / "summary.md"
    environ = {"GITHUB_STEP_SUMMARY": str(summary)}
    with jobsummary.job_record(environ) as path:
        assert environ[jobsummary.RECORD_ENV] == str(path)
        for entry in ENTRIES:  # (each task process: its own append)
            jobsummary.record(entry, dict(environ))
        with jobsummary.job_record(environ) as inner:  # a job inside: the outer one writes
            assert inner == path
        assert not summary.exists()
    assert jobsummary.RECORD_ENV not in environ and not path.exists()
    assert summary.read_text() == jobsummary.render_summary(ENTRIES) + "\n"
    jobsummary.record(ENTRIES[0], environ)  # (outside a job: nothing recorded)


def test_a_failed_job_still_summarizes_what_it_made(tmp_path):
    summary = tmp_path / "summary.md"
    environ = {"GITHUB_STEP_SUMMARY": str(summary)}
    with pytest.raises(RuntimeError), jobsummary.job_record(environ):
        jobsummary.record(ENTRIES[0], environ)
        raise RuntimeError("push failed")
    assert "`reg/robot:1-dev`" in summary.read_text()
    # without GitHub's summary file: nothing written anywhere
    with jobsummary.job_record({}) as path:
        jobsummary.record(ENTRIES[0], {jobsummary.RECORD_ENV: str(path)})
    assert os.listdir(tmp_path) == ["summary.md"]
