"""Tests of the workspace (`inv test`, ENABLE_INDUSTRIAL_CI): colcon build, colcon test and
colcon test-result in the image's `test` stage; JUnit XML, logs and exit codes come out.

Standard library only, Python 3.8: `python3 -m docker_ros.in_image.testing DESTINATION` runs
inside the image. It records the outcome in files instead of failing the RUN, so that the
results can be exported (`--output type=local`) whatever happened; the host reads them with
the same code.
"""

import json
import logging
import os
import re
import shutil
import sys
import xml.etree.ElementTree as ElementTree
from pathlib import Path
from typing import Dict, Iterable, Iterator, List, NamedTuple, Optional, Sequence, Tuple

from docker_ros.core.loading import load_settings
from docker_ros.in_image.runtime.entry import image_main
from docker_ros.in_image.runtime.process import run_tee
from docker_ros.in_image.runtime.rosenv import ros_setup_files, sourced_env
from docker_ros.in_image.runtime.workspace import DEFAULT_WORKSPACE, StepError, Workspace
from docker_ros.in_image.steps import colcon
from docker_ros.in_image.steps.blacklist import blacklisted_packages
from docker_ros.in_image.steps.colcon import SEE_ABOVE

LOG = logging.getLogger(__name__)
STEP = "test"
MARKER = ".docker-ros-test-results"  # a results folder we made (and may replace)
OUTCOME = "outcome.json"
JUNIT = "junit"
TEST_RESULT_LOG = "test-result.txt"
BUILD_ERROR = "colcon-build-error.txt"  # the colcon step's one-line error, when the build failed
CASES_SHOWN = 5  # failed test cases named in the verdict (all of them are in the JUnit XML)


class Counts(NamedTuple):
    passed: int = 0
    failed: int = 0
    skipped: int = 0

    def plus(self, other: "Counts") -> "Counts":
        return Counts(*(a + b for a, b in zip(self, other)))


# rostest's own test case for each <test> of a .test file ("did the test node run and write its
# results"): when it passes, the node's results file (rosunit-<name>.xml) holds the real cases
ROSTEST_WRAPPER = "rostest.runner.RosTest"


def junit_cases(text: str) -> Optional[List[Tuple[str, str, str]]]:
    """(name, outcome: passed, failed or skipped, the first line of a failure's message) of
    each test case of a JUnit/xUnit XML document, a passing rostest wrapper case left out (its
    test's own file counts them); None when the XML is not a JUnit report (e.g. CTest's own
    Test.xml, a package.xml)."""
    try:
        root = ElementTree.fromstring(text)
    except ElementTree.ParseError:
        return None
    if root.tag not in ("testsuites", "testsuite"):
        return None
    cases = []
    for case in root.iter("testcase"):
        children = {child.tag for child in case}
        classname = case.get("classname", "")
        failures = [child for child in case if child.tag in ("failure", "error")]
        message = failure_message(failures[0]) if failures else ""
        if failures:
            outcome = "failed"
        elif "skipped" in children or case.get("status") in ("notrun", "disabled"):
            outcome = "skipped"
        elif classname == ROSTEST_WRAPPER:
            continue
        else:
            outcome = "passed"
        cases.append((case_name(classname, case.get("name", "")), outcome, message))
    return cases


# pytest's message of the case it reports for a test module it could not import (and then
# runs no test of the package)
PYTEST_COLLECTION_FAILURE = "collection failure"


def failure_message(failure: ElementTree.Element) -> str:
    """The first line of a <failure>/<error>'s message: its message attribute (gtest, pytest),
    else its text (rosunit and rostest write none: `<failure type="AssertionError">5 != 6`);
    a first line ending in ':' with the next one (the ament linters' tests: `Found 1 code
    style errors / warnings:`, then the first of them); pytest's `collection failure` with
    its cause (`ModuleNotFoundError: No module named 'x'`: a test dependency missing)."""
    text = failure.get("message") or failure.text or ""
    if text == PYTEST_COLLECTION_FAILURE:  # its cause: the traceback's last `E   ` line
        causes = [line[1:].strip() for line in (failure.text or "").splitlines()
                  if line.startswith("E ")]
        text += f": {causes[-1]}" if causes else ""
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    if len(lines) > 1 and lines[0].endswith(":"):
        lines[0] += " " + lines[1]
    return lines[0][:150] if lines else ""


def case_name(classname: str, name: str) -> str:
    """`Class.name` (a script's `__main__.` dropped); rostest's case for a <test>, which
    rostest names `test<test-name>`, is `rostest <test-name>`."""
    if classname == ROSTEST_WRAPPER:
        return "rostest " + (name[len("test"):] if name.startswith("test") else name)
    if classname.startswith("__main__."):
        classname = classname[len("__main__."):]
    return f"{classname}.{name}" if classname else name or "(a test case without a name)"


def parse_junit(text: str) -> Optional[Counts]:
    """Count the test cases of a JUnit/xUnit XML document (failure or error: failed); None
    when the XML is not a JUnit report."""
    cases = junit_cases(text)
    return None if cases is None else counted(outcome for _, outcome, _ in cases)


def counted(outcomes: Iterable[str]) -> Counts:
    listed = list(outcomes)
    return Counts(*(listed.count(kind) for kind in ("passed", "failed", "skipped")))


def junit_reports(root: Path) -> Iterator[Tuple[Path, List[Tuple[str, str, str]]]]:
    """The JUnit reports below root (colcon test-result's search, minus the non-reports), each
    with its test cases (junit_cases)."""
    for dirpath, dirnames, filenames in os.walk(str(root)):
        dirnames.sort()
        for name in sorted(filenames):
            path = Path(dirpath, name)
            cases = junit_cases(path.read_text(errors="replace")) if name.endswith(".xml") \
                else None
            if cases is not None:
                yield path, cases


def summarize(root: Path) -> Counts:
    return counted(outcome for _, cases in junit_reports(root) for _, outcome, _ in cases)


def failed_cases(root: Path) -> List[str]:
    """`<package>: <test> (<first line of the failure's message>)` of each failed test case in
    the JUnit reports below root (the package: the report's first folder, as colcon's build/
    has them; left out when the test's name starts with it, as colcon's pytest names them)."""
    found = []
    for path, cases in junit_reports(root):
        parts = path.relative_to(root).parts
        package = parts[0] if len(parts) > 1 else ""
        for name, outcome, message in cases:
            if outcome != "failed":
                continue
            if package and not name.startswith(package + "."):
                name = f"{package}: {name}"
            message = message.replace(f"{DEFAULT_WORKSPACE}/src/target/", "")  # as in the repo
            found.append(name + (f" ({message})" if message else ""))
    return found


# colcon's last line of a package's test command.log: "Invoked command in '<dir>' returned
# '<code>': <environment> <command>"
_INVOKED = re.compile(r"^Invoked command in '[^']*' returned '(-?\d+)': (.*)$")
NO_TESTS_CODE = 5  # unittest's and pytest's exit code when no test ran
UNITTEST_HINT = ("colcon ran `python3 -m unittest`, which finds only unittest.TestCase classes; "
                 "it runs pytest when setup.py declares it: extras_require={'test': ['pytest']} "
                 "(setuptools >= 72 ignores tests_require)")


def package_test_failures(log: Path) -> List[str]:
    """`<package>: <test command> exited with N` for each package whose test command failed,
    from colcon's test logs (log/test/<package>/command.log); a Python package in which no
    test ran is said so, with why when colcon fell back to unittest."""
    found = []
    for command_log in sorted(log.glob("*/command.log")):
        package = command_log.parent.name
        match = None
        for line in command_log.read_text(errors="replace").splitlines():
            match = _INVOKED.match(line) or match
        if match is None or match.group(1) == "0":
            continue
        code, command = int(match.group(1)), match.group(2)
        if code == NO_TESTS_CODE and re.search(r"-m (unittest|pytest)\b", command):
            unittest = "-m unittest" in command
            found.append(f"{package}: no tests ran" + (f" ({UNITTEST_HINT})" if unittest else
                                                       " (pytest collected none)"))
        else:
            found.append(f"{package}: its tests exited with code {code}")
    return found


def format_summary(counts: Counts) -> str:
    return f"{counts.passed} passed, {counts.failed} failed, {counts.skipped} skipped"


def verdict(outcome: Dict[str, int], counts: Counts, cases: Sequence[str] = (),
            build_error: str = "", packages: Sequence[str] = ()) -> Optional[str]:
    """None when everything passed, else what failed (one line): the failed test cases
    (failed_cases), the packages whose tests failed without a failed case
    (package_test_failures) or the colcon step's error (BUILD_ERROR) named."""
    if outcome.get("colcon_build", 0) != 0:
        # (the task's message says it once at its end)
        cause = build_error[:-len(SEE_ABOVE)] if build_error.endswith(SEE_ABOVE) else build_error
        return (f"colcon build failed (exit code {outcome['colcon_build']}): no tests ran"
                + (f" ({cause})" if cause else ""))
    if counts.failed:
        shown = ", ".join(cases[:CASES_SHOWN]) + (
            f" and {len(cases) - CASES_SHOWN} more" if len(cases) > CASES_SHOWN else "")
        return f"{counts.failed} test(s) failed" + (f": {shown}" if shown else "")
    if outcome.get("colcon_test", 0) != 0:
        return (f"colcon test failed (exit code {outcome['colcon_test']})"
                + (": " + "; ".join(packages) if packages else ""))
    if outcome.get("colcon_test_result", 0) != 0:
        return f"colcon test-result reported failures (exit code {outcome['colcon_test_result']})"
    return None


def colcon_test_argv(ignore: Sequence[str]) -> List[str]:
    argv = ["colcon", "test", "--base-paths", "src", "--event-handlers", "console_cohesion+"]
    return argv + (["--packages-ignore", *ignore] if ignore else [])


TEST_RESULT_ARGV = ["colcon", "test-result", "--test-result-base", "build", "--verbose"]
# Results of an earlier run in the build/ cache mount would be counted again.
DELETE_RESULTS_ARGV = ["colcon", "test-result", "--test-result-base", "build", "--delete-yes"]


def copy_results(ws_root: Path, destination: Path, *, junit: bool = True) -> None:
    """JUnit reports from build/ (keeping their paths; junit=False: none, when no test ran,
    as build/ then holds an earlier run's) and the build and test logs."""
    for path, _ in junit_reports(ws_root / "build") if junit else ():
        target = destination / JUNIT / path.relative_to(ws_root / "build")
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(str(path), str(target))
    for name in ("latest_build", "latest_test"):
        log = ws_root / "log" / name
        if log.exists():
            shutil.copytree(str(log.resolve()), str(destination / "log" / name[len("latest_"):]))


def run_in_image(ws_root: Path, destination: Path, environ: Dict[str, str]) -> Dict[str, int]:
    """colcon build (as the build stage: same arguments, same build/ cache), colcon test,
    colcon test-result; returns and records the exit codes, never raises for a failed test."""
    ws = Workspace(ws_root)
    settings = load_settings(environ=environ, project_dir=Path(ws.target))
    destination.mkdir(parents=True, exist_ok=True)
    (destination / MARKER).write_text("made by docker-ros test; replaced by the next run\n")
    outcome = {"colcon_build": 0, "colcon_test": 0, "colcon_test_result": 0}
    try:
        colcon.main(ws, settings, stamp_changed=True)
    except StepError as exc:
        LOG.error("docker-ros %s: %s", STEP, exc.message)
        outcome["colcon_build"] = exc.returncode or 1
        (destination / BUILD_ERROR).write_text(exc.message + "\n")
    if outcome["colcon_build"] == 0:
        env = sourced_env(ros_setup_files(settings), step=STEP)
        run_tee(DELETE_RESULTS_ARGV, step=STEP, cwd=ws.root, env=env)
        outcome["colcon_test"], _ = run_tee(
            colcon_test_argv(blacklisted_packages(ws, settings)), step=STEP, cwd=ws.root, env=env
        )
        outcome["colcon_test_result"], lines = run_tee(
            TEST_RESULT_ARGV, step=STEP, cwd=ws.root, env=env
        )
        (destination / TEST_RESULT_LOG).write_text("".join(line + "\n" for line in lines))
    # a failed build ran no test: the reports in the build/ cache mount are an earlier run's
    copy_results(ws.root, destination, junit=outcome["colcon_build"] == 0)
    (destination / OUTCOME).write_text(json.dumps(outcome, sort_keys=True) + "\n")
    counts = summarize(destination / JUNIT)
    LOG.info("%s: %s", STEP, format_summary(counts))
    return outcome


def read_outcome(results: Path) -> Dict[str, int]:
    path = results / OUTCOME
    if not path.is_file():
        raise FileNotFoundError(f"{path} not found: the test stage did not record its outcome")
    data = json.loads(path.read_text())
    return {str(k): int(v) for k, v in data.items()}


def read_build_error(results: Path) -> str:
    """The colcon step's error the test stage recorded ('' when the build did not fail)."""
    path = results / BUILD_ERROR
    return path.read_text().strip() if path.is_file() else ""


def check_results_dir(path: Path) -> Optional[str]:
    """Why path cannot take the results (None: it can). Only an empty folder or one an earlier
    run made is replaced: nothing of the user's is ever deleted."""
    if path.is_file():
        return f"{path} is a file; give a folder"
    if path.is_dir() and any(path.iterdir()) and not (path / MARKER).is_file():
        return f"{path} is not empty and was not made by docker-ros test; give another folder"
    existing = next(p for p in (path, *path.parents) if p.exists())
    if not existing.is_dir():
        return f"{path} cannot be made: {existing} is not a folder; give a writable folder"
    if not os.access(existing, os.W_OK | os.X_OK):
        return f"{path} cannot be written ({existing} is read-only); give a writable folder"
    return None


def install_results(exported: Path, results: Path) -> None:
    """Move the exported results to results (replacing an earlier run's)."""
    if results.is_dir():
        shutil.rmtree(str(results))
    results.parent.mkdir(parents=True, exist_ok=True)
    shutil.copytree(str(exported), str(results))


def main(argv: Optional[Sequence[str]] = None) -> int:
    return image_main(sys.argv[1:] if argv is None else argv, module="testing", step=STEP,
                      description="colcon build, test and test-result in the workspace; exit "
                      "codes, JUnit XML and logs go to DESTINATION (settings from the "
                      "environment).", arguments=["DESTINATION"], settings=False,
                      action=lambda ws, _, args: run_in_image(ws.root, Path(args[0]),
                                                              dict(os.environ)))


if __name__ == "__main__":
    sys.exit(main())
