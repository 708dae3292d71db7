"""`inv test`'s pure parts: JUnit counting, the verdict, the results folder, the build plan."""

import errno
import os
from pathlib import Path

import pytest

from docker_ros.core.loading import load_settings
from docker_ros.host import build, buildcontext, buildplan
from docker_ros.in_image import testing
from docker_ros.in_image.testing import Counts

# What pytest writes for colcon (one passed, one failed, one skipped).
PYTEST_XML = """<?xml version="1.0" encoding="utf-8"?><testsuites><testsuite name="pytest"
 errors="0" failures="1" skipped="1" tests="3"><testcase classname="t" name="test_passes"/>
<testcase classname="t" name="test_fails"><failure message="boom">trace</failure></testcase>
<testcase classname="t" name="test_skipped"><skipped type="pytest.skip" message="x"/></testcase>
</testsuite></testsuites>"""
# ament_cmake/gtest style: a bare testsuite, an error, a disabled case.
GTEST_XML = """<testsuite name="gtest" tests="4"><testcase name="a" status="run"/>
<testcase name="b" status="run"><error message="crash"/></testcase>
<testcase name="c" status="notrun"/><testcase name="d"/></testsuite>"""
CTEST_SITE_XML = '<Site BuildName="x"><Testing><Test Status="passed"/></Testing></Site>'


def test_junit_counts_pass_fail_skip():
    assert testing.parse_junit(PYTEST_XML) == Counts(1, 1, 1)
    assert testing.parse_junit(GTEST_XML) == Counts(2, 1, 1)


def test_what_is_not_a_junit_report_is_not_counted():
    assert testing.parse_junit(CTEST_SITE_XML) is None
    assert testing.parse_junit("<package><name>x</name></package>") is None
    assert testing.parse_junit("not xml <") is None


def test_summary_adds_every_report_below_a_folder(tmp_path: Path):
    (tmp_path / "a" / "deep").mkdir(parents=True)
    (tmp_path / "a" / "pytest.xml").write_text(PYTEST_XML)
    (tmp_path / "a" / "deep" / "gtest.xml").write_text(GTEST_XML)
    (tmp_path / "a" / "package.xml").write_text("<package/>")
    (tmp_path / "a" / "notes.txt").write_text(PYTEST_XML)
    assert testing.summarize(tmp_path) == Counts(3, 2, 2)
    assert testing.format_summary(testing.summarize(tmp_path)) == "3 passed, 2 failed, 2 skipped"
    assert testing.format_summary(testing.summarize(tmp_path / "missing")) == (
        "0 passed, 0 failed, 0 skipped")


# What a rostest (.test file with one <test> of a Python unittest node, one of its two cases
# failing) and a catkin_add_gtest write in build/<pkg>/test_results/<pkg>/ (Debian's ROS 1,
# output trimmed): rostest's own case for the <test> passes whenever the node wrote results.
ROSTEST_WRAPPER_XML = """<?xml version="1.0" encoding="utf-8"?>
<testsuite errors="0" failures="0" name="unittest.suite.TestSuite" tests="1" time="1.717">\
<testcase classname="rostest.runner.RosTest" name="testgreeting_test" time="1.7165" />\
<system-out/><system-err/></testsuite>"""
ROSTEST_NO_RESULTS_XML = """<?xml version="1.0" encoding="utf-8"?>
<testsuite errors="0" failures="1" name="unittest.suite.TestSuite" tests="1" time="2.1">\
<testcase classname="rostest.runner.RosTest" name="testgreeting_test" time="2.1">\
<failure type="AssertionError">test [greeting_test] did not generate test results</failure>\
</testcase></testsuite>"""
ROSUNIT_XML = """<?xml version="1.0" encoding="utf-8"?>
<testsuite errors="0" failures="1" name="unittest.suite.TestSuite" tests="2" time="0.397">\
<testcase classname="__main__.GreetingTest" name="test_add_two" time="0.1898">\
<failure type="AssertionError">5 != 6</failure></testcase>\
<testcase classname="__main__.GreetingTest" name="test_greeting_arrives" time="0.2068" />\
<system-out/><system-err/></testsuite>"""
CATKIN_GTEST_XML = """<?xml version="1.0" encoding="UTF-8"?>
<testsuites tests="2" failures="1" disabled="0" errors="0" time="0.001" name="AllTests">
  <testsuite name="Utils" tests="2" failures="1" disabled="0" skipped="0" errors="0" time="0">
    <testcase name="Adds" status="run" result="completed" time="0" classname="Utils" />
    <testcase name="Multiplies" status="run" result="completed" time="0" classname="Utils">
      <failure message="utils_test.cpp:3" type=""><![CDATA[utils_test.cpp:3]]></failure>
    </testcase>
  </testsuite>
</testsuites>"""


def test_a_rostest_counts_its_test_cases_not_its_wrapper(tmp_path: Path):
    """A rostest with two cases, one failing, is 1 passed and 1 failed (before: rostest's own
    passing case made it 2 passed); a test node that wrote no results is its wrapper's failure."""
    results = tmp_path / "junit" / "demo_nodes" / "test_results" / "demo_nodes"
    results.mkdir(parents=True)
    (results / "rostest-test_demo.xml").write_text(ROSTEST_WRAPPER_XML)
    (results / "rosunit-greeting_test.xml").write_text(ROSUNIT_XML)
    (results / "gtest-utils_test.xml").write_text(CATKIN_GTEST_XML)
    assert testing.summarize(tmp_path / "junit") == Counts(2, 2, 0)
    assert testing.failed_cases(tmp_path / "junit") == [
        "demo_nodes: Utils.Multiplies (utils_test.cpp:3)",
        "demo_nodes: GreetingTest.test_add_two (5 != 6)"]  # rosunit's message: the text
    assert testing.parse_junit(ROSTEST_NO_RESULTS_XML) == Counts(0, 1, 0)
    (results / "rostest-test_demo.xml").write_text(ROSTEST_NO_RESULTS_XML)
    (results / "rosunit-greeting_test.xml").unlink()
    assert ("demo_nodes: rostest greeting_test (test [greeting_test] did not generate test "
            "results)") in testing.failed_cases(tmp_path / "junit")


def test_the_verdict_names_the_failed_tests():
    ok = {"colcon_build": 0, "colcon_test": 0, "colcon_test_result": 0}
    names = ["demo_nodes: Utils.Multiplies", "demo_nodes: GreetingTest.test_add_two"]
    assert testing.verdict(ok, Counts(2, 2, 0), names) == (
        "2 test(s) failed: demo_nodes: Utils.Multiplies, demo_nodes: GreetingTest.test_add_two")
    many = [f"p: t{i}" for i in range(7)]
    assert testing.verdict(ok, Counts(0, 7, 0), many) == (
        "7 test(s) failed: p: t0, p: t1, p: t2, p: t3, p: t4 and 2 more")


def test_verdict_names_what_failed():
    ok = {"colcon_build": 0, "colcon_test": 0, "colcon_test_result": 0}
    assert testing.verdict(ok, Counts(3, 0, 1)) is None
    assert testing.verdict(ok, Counts(1, 2, 0)) == "2 test(s) failed"
    assert "colcon build failed (exit code 2)" in str(
        testing.verdict({**ok, "colcon_build": 2}, Counts()))
    assert "colcon test failed (exit code 1)" in str(
        testing.verdict({**ok, "colcon_test": 1}, Counts(1, 0, 0)))
    assert "test-result" in str(testing.verdict({**ok, "colcon_test_result": 1}, Counts(1, 0, 0)))


def test_verdict_names_the_failed_test_cases_and_the_build_error(tmp_path: Path):
    """`inv test`'s last line says which tests failed (package: class.name, as the JUnit XML
    under junit/<package>/ has them), or why colcon build failed, not only how many."""
    (tmp_path / "my_pkg" / "test_results" / "my_pkg").mkdir(parents=True)
    (tmp_path / "my_pkg" / "pytest.xml").write_text(PYTEST_XML)
    (tmp_path / "my_pkg" / "test_results" / "my_pkg" / "gtest.xml").write_text(GTEST_XML)
    cases = testing.failed_cases(tmp_path)
    assert cases == ["my_pkg: t.test_fails (boom)", "my_pkg: b (crash)"]
    # colcon's pytest reports name the package already: `my_pkg.test.test_x`
    (tmp_path / "my_pkg" / "pytest.xml").write_text(PYTEST_XML.replace('classname="t"',
                                                                       'classname="my_pkg.t"'))
    assert testing.failed_cases(tmp_path)[0] == "my_pkg.t.test_fails (boom)"
    ok = {"colcon_build": 0, "colcon_test": 0, "colcon_test_result": 0}
    assert testing.verdict(ok, testing.summarize(tmp_path), cases) == (
        "2 test(s) failed: my_pkg: t.test_fails (boom), my_pkg: b (crash)")
    many = [f"p: t.case{n}" for n in range(7)]
    assert testing.verdict(ok, Counts(0, 7, 0), many) == (
        "7 test(s) failed: p: t.case0, p: t.case1, p: t.case2, p: t.case3, p: t.case4 and 2 more")
    assert testing.verdict({**ok, "colcon_build": 2}, Counts(), [], "package x failed to build "
                           "(exit code 2): x.cpp:1:1: error: y; see the output above") == (
        "colcon build failed (exit code 2): no tests ran (package x failed to build (exit code "
        "2): x.cpp:1:1: error: y)")


def test_results_folder_is_replaced_only_when_empty_or_ours(tmp_path: Path):
    assert testing.check_results_dir(tmp_path / "new") is None
    assert testing.check_results_dir(tmp_path) is None  # empty
    (tmp_path / "mine.txt").write_text("the user's")
    assert "not empty" in str(testing.check_results_dir(tmp_path))
    (tmp_path / "file").write_text("")
    assert "is a file" in str(testing.check_results_dir(tmp_path / "file"))
    ours = tmp_path / "ours"
    exported = tmp_path / "exported"
    (exported / "junit").mkdir(parents=True)
    (exported / testing.MARKER).write_text("")
    (exported / "junit" / "new.xml").write_text(PYTEST_XML)
    ours.mkdir()
    (ours / testing.MARKER).write_text("")
    (ours / "stale.xml").write_text(PYTEST_XML)
    assert testing.check_results_dir(ours) is None
    testing.install_results(exported, ours)
    assert sorted(p.name for p in ours.rglob("*")) == [testing.MARKER, "junit", "new.xml"]


def test_colcon_test_ignores_blacklisted_packages():
    assert testing.colcon_test_argv([]) == [
        "colcon", "test", "--base-paths", "src", "--event-handlers", "console_cohesion+"]
    assert testing.colcon_test_argv(["a", "b"])[-3:] == ["--packages-ignore", "a", "b"]


def test_test_plan_exports_results_and_reruns_every_time():
    settings = load_settings(environ={"BASE_IMAGE": "base:1", "COMMAND": "x"},
                             project_dir=Path("/tmp/robot"))
    argv = buildplan.plan_build(settings, target="test-results", platform="amd64",
                            tools_image="tools:x", tag="t:1", secrets={},
                            output="type=local,dest=/tmp/out",
                            extra_build_args={"DOCKER_ROS_TEST_RUN": "42"})
    assert argv[argv.index("--output") + 1] == "type=local,dest=/tmp/out"
    assert "--load" not in argv and "--push" not in argv
    assert "DOCKER_ROS_TEST_RUN=42" in argv
    dockerfile = buildcontext.DOCKERFILE.read_text()
    assert "FROM dev AS test" in dockerfile and "FROM scratch AS test-results" in dockerfile
    # the same build/ cache as the build stage, so a test after a build compiles nothing
    build_mounts = [line for line in dockerfile.splitlines()
                    if "target=/docker-ros/ws/build,id=" in line]
    # (the build stage's, the test stage's, and build-state's copy of it)
    assert len(build_mounts) == 3
    assert len({m.strip().replace("RUN ", "", 1) for m in build_mounts}) == 1


def test_results_go_to_the_flag_else_test_results_dir_else_the_workspace(tmp_path: Path):
    from docker_ros.host.pipeline import results_root

    env = {"BASE_IMAGE": "base:1", "WORKSPACE": str(tmp_path / "ws")}
    plain = load_settings(environ=env, project_dir=tmp_path)
    assert results_root(plain, "") == tmp_path / "ws" / "test-results"
    named = load_settings(environ={**env, "TEST_RESULTS_DIR": str(tmp_path / "ci")},
                          project_dir=tmp_path)
    assert results_root(named, "") == tmp_path / "ci"
    assert results_root(named, str(tmp_path / "flag")) == tmp_path / "flag"


@pytest.fixture
def read_only() -> Path:
    """A folder nobody may write to, root included, on every Linux machine: a sysctl folder
    (procfs refuses to create anything in /proc/sys; in a container /proc/sys is mounted
    read-only as well). No chattr, which some file systems and containers refuse."""
    folder = Path("/proc/sys")
    assert folder.is_dir() and not os.access(folder, os.W_OK), "/proc/sys is writable here"
    return folder


def test_a_results_dir_that_cannot_be_written_is_refused_up_front(read_only: Path) -> None:
    assert testing.check_results_dir(read_only / "res") == (
        f"{read_only / 'res'} cannot be written ({read_only} is read-only); give a writable "
        "folder")
    assert testing.check_results_dir(Path("/dev/null/res")) == (
        "/dev/null/res cannot be made: /dev/null is not a folder; give a writable folder")


def test_results_dir_errors_name_where_the_folder_came_from(tmp_path: Path) -> None:
    from docker_ros.host.pipeline import results_origin

    env = {"BASE_IMAGE": "base:1", "WORKSPACE": str(tmp_path / "ws")}
    plain = load_settings(environ=env, project_dir=tmp_path)
    assert results_origin(plain, "") == "TEST_RESULTS_DIR (default: in WORKSPACE, environment)"
    named = load_settings(environ=env, flags={"test_results_dir": "x"}, project_dir=tmp_path)
    assert results_origin(named, "") == "TEST_RESULTS_DIR (flag)"
    assert results_origin(named, "y") == "--results-dir"


def test_a_copy_that_fails_late_is_the_tasks_error(tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    from docker_ros.host import pipeline

    def refuse(exported: Path, results: Path) -> None:
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(results))

    monkeypatch.setattr(build, "check_engine", lambda settings: None)
    monkeypatch.setattr(build, "build_image", lambda settings, **kwargs: None)
    monkeypatch.setattr(testing, "read_outcome", lambda folder: {})
    monkeypatch.setattr(testing, "install_results", refuse)
    settings = load_settings(environ={"BASE_IMAGE": "base:1", "PLATFORM": "amd64",
                                      "TEST_RESULTS_DIR": str(tmp_path / "res")},
                             project_dir=tmp_path)
    with pytest.raises(pipeline.TaskError) as raised:
        pipeline.run_test_stage(settings, results_dir="", dry_run=False)
    assert str(raised.value) == (
        f"TEST_RESULTS_DIR (environment): cannot copy the results to {tmp_path / 'res'}: "
        "Read-only file system; give a writable folder")


def test_a_results_folder_in_the_build_context_is_warned_about(tmp_path: Path) -> None:
    """Results written into the repository change the next build's context (a full colcon
    build, the dev image's sources): `inv test` says so; a folder outside stays silent."""
    from docker_ros.host.pipeline import results_in_context

    repo = tmp_path / "repo"
    repo.mkdir()
    warning = results_in_context(repo / "test-results", repo, "--results-dir")
    assert warning is not None
    assert warning.startswith(f"docker-ros test: warning: --results-dir: {repo / 'test-results'}"
                              f" is in the build context ({repo})")
    assert "outside the repository" in warning
    assert results_in_context(repo, repo, "--results-dir") is not None
    assert results_in_context(tmp_path / "results", repo, "--results-dir") is None
    assert results_in_context(tmp_path / "repo-results", repo, "--results-dir") is None
    # a folder the build leaves out (ours: the CI template's docker-ros-test-results)
    assert results_in_context(repo / "docker-ros-test-results", repo, "--results-dir") is None


def test_a_failed_build_reports_no_earlier_runs_tests(tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """colcon build fails in the test stage: no test ran, so the JUnit reports an earlier run
    left in the build/ cache mount are neither copied out nor counted (they said
    '3 passed' next to 'no tests ran'); the build log still is."""
    from docker_ros.in_image.runtime.workspace import StepError
    from docker_ros.in_image.steps import colcon

    ws = tmp_path / "ws"
    (ws / "build" / "pkg" / "test_results").mkdir(parents=True)
    (ws / "build" / "pkg" / "test_results" / "pytest.xml").write_text(PYTEST_XML)
    (ws / "log" / "build_1").mkdir(parents=True)
    (ws / "log" / "build_1" / "events.log").write_text("failed\n")
    (ws / "log" / "latest_build").symlink_to("build_1")
    (ws / "src" / "target").mkdir(parents=True)

    def fail(*args: object, **kwargs: object) -> None:
        raise StepError("colcon", "package pkg failed to build (exit code 2)", 2)

    monkeypatch.setattr(colcon, "main", fail)
    results = tmp_path / "results"
    outcome = testing.run_in_image(ws, results, {})
    assert outcome == {"colcon_build": 2, "colcon_test": 0, "colcon_test_result": 0}
    assert testing.summarize(results / testing.JUNIT) == Counts(0, 0, 0)
    assert not (results / testing.JUNIT).exists()
    assert (results / "log" / "build" / "events.log").is_file()
    assert testing.read_build_error(results) == "package pkg failed to build (exit code 2)"


def test_repositories_of_the_same_folder_name_keep_their_own_results(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """~/a/robot and ~/b/robot: `inv test` of one replaced the other's results in the shared
    default ~/.cache/docker-ros/ws/robot/test-results (the host steps refused that workspace,
    `inv test` did not look). The first keeps the documented default, the second gets a
    workspace of its own; a WORKSPACE given for both is refused as the host steps refuse it."""
    from docker_ros.host import pipeline

    written = []
    monkeypatch.setattr(build, "check_engine", lambda settings: None)
    monkeypatch.setattr(build, "build_image", lambda settings, **kwargs: None)
    monkeypatch.setattr(testing, "read_outcome", lambda folder: {})
    monkeypatch.setattr(testing, "install_results", lambda exported, dest: written.append(dest))

    def test_in(repo: Path, **env: str) -> Path:
        repo.mkdir(parents=True, exist_ok=True)
        settings = load_settings(environ={"BASE_IMAGE": "base:1", "PLATFORM": "amd64",
                                          "XDG_CACHE_HOME": str(tmp_path / "cache"),
                                          "BUILD_CONTEXT": str(repo), **env},
                                 project_dir=repo)
        pipeline.run_test_stage(settings, results_dir="", dry_run=False)
        return written[-1]

    cache = tmp_path / "cache" / "docker-ros" / "ws"
    first = test_in(tmp_path / "a" / "robot")
    assert first == cache / "robot" / "test-results"  # the documented default
    second = test_in(tmp_path / "b" / "robot")
    assert second.parent.parent == cache and second.parent.name.startswith("robot-")
    assert test_in(tmp_path / "a" / "robot") == first  # each keeps its own, run after run
    assert test_in(tmp_path / "b" / "robot") == second
    b = load_settings(environ={"XDG_CACHE_HOME": str(tmp_path / "cache"),
                               "BUILD_CONTEXT": str(tmp_path / "b" / "robot")},
                      project_dir=tmp_path / "b" / "robot")
    assert b.workspace == str(second.parent)
    assert b.source_of("workspace") == (
        f"derived: {cache / 'robot'} is the workspace of {tmp_path / 'a' / 'robot'}")
    with pytest.raises(pipeline.TaskError, match=(
            f"src/target points to {tmp_path / 'a' / 'robot'}, not to "
            f"{tmp_path / 'b' / 'robot'}; set WORKSPACE to another folder")):
        test_in(tmp_path / "b" / "robot", WORKSPACE=str(cache / "robot"))


def test_a_test_case_without_a_name_is_named_as_such(tmp_path: Path):
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "r.xml").write_text(
        '<testsuite><testcase><failure message="boom"/></testcase></testsuite>')
    assert testing.failed_cases(tmp_path) == ["pkg: (a test case without a name) (boom)"]


# pytest's report of the ament_flake8 test of `ros2 pkg create --build-type ament_python`
# (colcon test on Debian trixie, shortened to the failed case)
AMENT_FLAKE8_FAILURE = """<?xml version="1.0" encoding="utf-8"?><testsuites><testsuite \
name="pytest" errors="0" failures="1" skipped="0" tests="1" time="0.149"><testcase \
classname="demo_py.test.test_flake8" name="test_flake8" time="0.048"><failure \
message="AssertionError: Found 1 code style errors / warnings:&#10;  ./demo_py/talker.py:16:100: \
E501 line too long (105 &gt; 99 characters)&#10;assert 1 == 0">test/test_flake8.py:9: in \
test_flake8
    assert rc == 0, "Found %d code style errors / warnings:\\n" % len(errors) + "\\n".join(errors)
E   AssertionError: Found 1 code style errors / warnings:
E     ./demo_py/talker.py:16:100: E501 line too long (105 &gt; 99 characters)
E   assert 1 == 0</failure></testcase></testsuite></testsuites>"""


def test_a_linter_failure_is_named_with_its_first_finding():
    assert testing.junit_cases(AMENT_FLAKE8_FAILURE) == [(
        "demo_py.test.test_flake8.test_flake8", "failed",
        "AssertionError: Found 1 code style errors / warnings: ./demo_py/talker.py:16:100: E501 "
        "line too long (105 > 99 characters)")]


# pytest's report of a test module it could not import (colcon test on Debian trixie)
PYTEST_COLLECTION_FAILURE = """<?xml version="1.0" encoding="utf-8"?><testsuites><testsuite \
name="pytest" errors="1" failures="0" skipped="0" tests="1" time="0.137"><testcase \
classname="demo_py" name="test.test_missing" time="0.000"><error message="collection failure">\
ImportError while importing test module '/docker-ros/ws/src/target/demo_py/test/test_missing.py'.
Hint: make sure your test modules/packages have valid Python names.
Traceback:
/usr/lib/python3.13/importlib/__init__.py:88: in import_module
    return _bootstrap._gcd_import(name[level:], package, level)
test/test_missing.py:1: in &lt;module&gt;
    import not_installed_mod
E   ModuleNotFoundError: No module named 'not_installed_mod'</error></testcase></testsuite>\
</testsuites>"""


def test_a_test_module_pytest_cannot_import_is_named_with_the_cause():
    assert testing.junit_cases(PYTEST_COLLECTION_FAILURE) == [(
        "demo_py.test.test_missing", "failed",
        "collection failure: ModuleNotFoundError: No module named 'not_installed_mod'")]
