"""A secret given as a flag is refused before invoke parses the command line, naming the task
it was given to; no task's --help lists a secret."""

import inspect

import pytest

from docker_ros.cli.settingstask import refuse_secret_flags, secret_flags_given
from docker_ros.cli.tasks import ns


@pytest.mark.parametrize("argv, task, given", [
    (["clone", "--git-ssh-private-key", "hunter2"], "clone", ["git_ssh_private_key"]),
    (["push", "--registry-password=hunter2"], "push", ["registry_password"]),
    # `run` is the value of --target here, not a task
    (["build", "--target", "run", "--registry-password"], "build", ["registry_password"]),
    (["--registry-password", "x", "build"], "", ["registry_password"]),
    (["build", "--", "--registry-password"], "", []),
    (["build", "--dry-run"], "", []),
])
def test_the_secret_flags_and_their_task_are_found(argv, task, given) -> None:
    found = secret_flags_given(argv, ns)
    assert found == (task if given else found[0], given)


def test_the_refusal_names_where_the_secret_goes_and_not_its_value(capsys) -> None:
    with pytest.raises(SystemExit) as stopped:
        refuse_secret_flags(["push", "--registry-password", "hunter2"], ns)
    assert stopped.value.code == 2
    err = capsys.readouterr().err
    assert err.strip() == (
        "docker-ros push: --registry-password: a secret is never a flag (a command line is "
        "visible to every process on this machine); set REGISTRY_PASSWORD in the environment "
        "or in the project's .env file")
    assert "hunter2" not in err


def test_no_task_declares_a_secret_flag() -> None:
    # (the signature: invoke's get_arguments would use up the tasks' help texts)
    for name in ns.task_names:
        flags = set(inspect.signature(ns[name].body).parameters)
        assert not flags & {"git_https_password", "git_ssh_private_key", "registry_password"}
