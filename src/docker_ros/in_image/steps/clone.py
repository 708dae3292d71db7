"""clone: run the before-dependency-identification hook, then import `.repos` files with vcstool
into src/upstream; recursive mode repeats until no new `.repos` file appears.

Every imported file is recorded (path, sha256, repositories) in clone.json, so a re-run imports
nothing twice. Credentials reach git only through the environment of the vcs process and files
in a private temporary directory that is removed when the step ends."""

import contextlib
import logging
import os
import re
import shutil
import stat
import tempfile
from pathlib import Path
from typing import Any, Dict, Iterator, List, Mapping, Optional, Sequence, Set

from docker_ros.core.display import server_host
from docker_ros.core.settings import Settings
from docker_ros.in_image.runtime import system
from docker_ros.in_image.runtime.apt import apt_install
from docker_ros.in_image.runtime.files import (
    file_sha256,
    find_special_files,
    remove_tree,
    repository_path,
)
from docker_ros.in_image.runtime.lock import pinned_repos_file
from docker_ros.in_image.runtime.lockfile import active_entry
from docker_ros.in_image.runtime.process import hook_context, is_root, run, run_script, run_tee
from docker_ros.in_image.runtime.repos import read_repos
from docker_ros.in_image.runtime.rosenv import SECRETS_DIR, read_secret
from docker_ros.in_image.runtime.workspace import (
    StepError,
    Workspace,
    dry,
    format_argv,
    phases,
    step_log,
)

STEP = "clone"
STATE_FILE = "clone.json"
MAX_ROUNDS = 50  # nested .repos levels; far more than any real workspace has
LOG = logging.getLogger(__name__)

# GIT_ASKPASS helper: answers git's prompts for the configured server only, from variables that
# exist only in the environment of the vcs process (never in a file, never on a command line).
# git asks "Username for 'https://host[:port]': " and "Password for 'https://user@host...': ":
# the host must end where the URL's host ends (github.com is not github.com.evil.example).
ASKPASS_SCRIPT = """#!/bin/sh
case "$1" in
  *"://$DOCKER_ROS_GIT_HTTPS_HOST'"*|*"://$DOCKER_ROS_GIT_HTTPS_HOST:"*) ;;
  *"@$DOCKER_ROS_GIT_HTTPS_HOST'"*|*"@$DOCKER_ROS_GIT_HTTPS_HOST:"*) ;;
  *) exit 1 ;;
esac
case "$1" in
  Username*) printf '%s\\n' "$DOCKER_ROS_GIT_HTTPS_USER" ;;
  *) printf '%s\\n' "$DOCKER_ROS_GIT_HTTPS_PASSWORD" ;;
esac
"""
_FAILURE = re.compile(
    r"^(Could not|Failed|fatal:|error:|ERROR|Repository type|Path .* already exists)"
    r"|already exists and (is|contains)",
    re.IGNORECASE,
)


# --- vcs output ---


def vcs_blocks(lines: Sequence[str], dest: Path, names: Sequence[str]) -> Dict[str, List[str]]:
    """The non-empty lines of each repository's `=== path (type) ===` block in vcs output."""
    blocks: Dict[str, List[str]] = {}
    current: Optional[List[str]] = None
    for line in lines:
        header = re.match(r"^=== (.+) \(\w+\) ===$", line.strip())
        if header:
            path = header.group(1)
            name = _repo_of(path, dest, names)
            current = blocks.setdefault(name, []) if name else None
        elif current is not None and line.strip():
            current.append(line.strip())
    return blocks


def parse_vcs_failures(lines: Sequence[str], dest: Path, names: Sequence[str]) -> Dict[str, str]:
    """Repositories whose `=== path (type) ===` block in vcs output reports an error, with
    vcstool's reason (first error line)."""
    return block_failures(vcs_blocks(lines, dest, names))


def block_failures(blocks: Mapping[str, Sequence[str]]) -> Dict[str, str]:
    """parse_vcs_failures of the blocks vcs_blocks found."""
    failures = {}
    for name, text in blocks.items():
        bad = [line for line in text if _FAILURE.search(line)]
        if not bad:
            continue
        reason = re.sub(r":\s*Cloning into .*$", "", bad[0])
        following = text[text.index(bad[0]) + 1:]
        if reason.endswith(":") and following:
            # git:// errors end the line before the cause: `unable to connect to HOST:` /
            # `HOST[0: ...]: errno=Connection refused`.
            reason += " " + following[0]
        detail = [line for line in bad if re.match(r"^(fatal|error):", line)]
        if detail and detail[0] not in reason:
            reason += ": " + detail[0]
        failures[name] = reason
    return failures


LOOPBACK = re.compile(r"^(localhost|127\.\d+\.\d+\.\d+|\[?::1\]?)$")
_CONNECT_FAILED = re.compile(r"connection refused|couldn't connect|failed to connect|"
                             r"unable to connect|could not resolve host", re.IGNORECASE)


def url_host(url: str) -> str:
    """The host of a git URL (scheme://[user@]host[:port]/..., or scp-like [user@]host:path)."""
    match = re.match(r"^[a-z+]+://(?:[^@/]*@)?(\[[^\]]*\]|[^:/]*)", url)
    if match:
        return match.group(1)
    if uses_ssh(url):
        return url.split(":", 1)[0].rpartition("@")[2]
    return ""


# The user information of a URL: what lies between `scheme://` and the last `@` before the host.
USERINFO = re.compile(r"\b([A-Za-z][A-Za-z0-9+.-]*://)([^/\s'\"]+)@")


def hide_url_passwords(text: str) -> str:
    """text as a message or the log shows it: in every URL, a password written into it
    (`https://user:pw@host/...`) or, over HTTP(S), a token standing alone
    (`https://ghp_...@github.com/...`) as `***` (an SSH user, `ssh://git@`, stays)."""
    def hidden(match: "re.Match[str]") -> str:
        user, colon, _ = match.group(2).partition(":")
        token = match.group(1).lower() in ("http://", "https://")
        shown = f"{user}:***" if colon else ("***" if token else user)
        return f"{match.group(1)}{shown}@"

    return USERINFO.sub(hidden, text)


_NOT_A_REPOSITORY = re.compile(r"does not appear to be a git repository|does not exist|"
                               r"no such file", re.IGNORECASE)


def is_local_url(url: str) -> bool:
    """Whether git reads the repository from a folder: a file:// URL or a path."""
    return url.startswith("file://") or ("://" not in url and not uses_ssh(url))


def failure_hint(url: str, reason: str, *, in_image: bool) -> str:
    """What to do about a clone failure we recognise (empty when we do not)."""
    if in_image and LOOPBACK.match(url_host(url)) and _CONNECT_FAILED.search(reason):
        # (the step cannot tell whether the build runs with BUILD_NETWORK=host)
        return (" (in an image build the loopback address is the build container itself unless "
                "BUILD_NETWORK=host: set it to reach a server on this machine; if it is set, "
                "nothing answered at that address on this machine: is the server running?)")
    if in_image and is_local_url(url) and _NOT_A_REPOSITORY.search(reason):
        return (" (in an image build a file:// URL or a path names a folder in the build "
                "container, not on this machine: serve the repository over HTTP(S) or SSH, "
                "with BUILD_NETWORK=host for a server on this machine)")
    return ""


# git's words when the server wants a login it did not get, refused the one it got, refused
# the SSH key, or its SSH host key is unknown
_LOGIN_WANTED = re.compile(r"could not read (username|password) for|terminal prompts disabled",
                           re.IGNORECASE)
_LOGIN_REFUSED = re.compile(r"authentication failed for|HTTP Basic: Access denied|"
                            r"returned error: 40[13]", re.IGNORECASE)
_KEY_REFUSED = re.compile(r"permission denied \(publickey", re.IGNORECASE)
_HOST_KEY_UNKNOWN = re.compile(r"host key verification failed", re.IGNORECASE)


def login_hint(url: str, output: Sequence[str], env: Mapping[str, str]) -> str:
    """What to do when a repository's clone failed for want of credentials (its vcs output
    lines; env: the clone's credential environment, see git_credentials), '' otherwise."""
    text = "\n".join(output)
    host = url_host(url)
    given = env.get("DOCKER_ROS_GIT_HTTPS_HOST", "")
    if _LOGIN_WANTED.search(text):
        if given and given.split(":")[0] != host:
            return (f" (the server asks for a login; GIT_HTTPS_SERVER is {given}, and the "
                    f"password is given to that host only: set it to {host})")
        return (f" (the server asks for a login: set GIT_HTTPS_SERVER={host}, GIT_HTTPS_USER "
                "and GIT_HTTPS_PASSWORD in the environment or .env)")
    if _LOGIN_REFUSED.search(text):
        if hide_url_passwords(url) != url:
            return (" (the server refused the user and password written into the URL: fix "
                    "them, or better take them out of the .repos file and set GIT_HTTPS_USER "
                    "and GIT_HTTPS_PASSWORD, which stay out of the images and logs)")
        return (" (the server refused the login: check GIT_HTTPS_USER and GIT_HTTPS_PASSWORD, "
                "and that the user may read the repository)")
    keyscan = f"`ssh-keyscan {host or 'HOST'}`"
    if (_KEY_REFUSED.search(text) or _HOST_KEY_UNKNOWN.search(text)) \
            and "GIT_SSH_COMMAND" not in env:
        # (without a key, GIT_SSH_KNOWN_HOST_KEYS is not used either)
        return (" (the server wants an SSH login: set GIT_SSH_PRIVATE_KEY and "
                f"GIT_SSH_KNOWN_HOST_KEYS (its lines from {keyscan}) in the environment or .env)")
    if _KEY_REFUSED.search(text):
        return " (the server refused GIT_SSH_PRIVATE_KEY: give a key it accepts)"
    if _HOST_KEY_UNKNOWN.search(text):
        return (" (the server's SSH host key is not known: set GIT_SSH_KNOWN_HOST_KEYS to its "
                f"lines from {keyscan})")
    return ""


def _repo_of(path: str, dest: Path, names: Sequence[str]) -> Optional[str]:
    for name in sorted(names, key=len, reverse=True):
        if Path(path) == dest / name or path.rstrip("/").endswith("/" + name) or path == name:
            return name
    return None


# --- credentials ---


def uses_ssh(url: str) -> bool:
    """Whether git clones `url` over SSH: ssh:// (git+ssh://, ssh+git://) URLs and the
    scp-like `[user@]host:path` form (a colon before the first slash, no scheme)."""
    if re.match(r"^(ssh|git\+ssh|ssh\+git)://", url):
        return True
    return "://" not in url and ":" in url.split("/", 1)[0]


def require_ssh(repos: Mapping[str, Mapping[str, str]], env: Mapping[str, str]) -> None:
    """git runs `ssh` for SSH URLs: without it, fail naming the repositories (git's own message,
    'ssh: not found', is buried in vcstool's output)."""
    own_program = os.environ.get("GIT_SSH_COMMAND") or os.environ.get("GIT_SSH")
    if own_program and "GIT_SSH_COMMAND" not in env:
        return  # the user's own ssh program, not ours
    needing = sorted(name for name, spec in repos.items() if uses_ssh(spec.get("url", "")))
    if not needing or shutil.which("ssh"):
        return
    if os.environ.get("DOCKER_ROS") == "1" and is_root():
        # In the image's source stage, which no image ships: fetch ssh for the clone only.
        LOG.info("%s: installing openssh-client for SSH clones (source stage only)", STEP)
        apt_install(["openssh-client"], step=STEP, dry_run=False, what="installing ssh")
        if shutil.which("ssh"):
            return
    listed = ", ".join(f"'{name}' ({hide_url_passwords(repos[name]['url'])})" for name in needing)
    what = "repository" if len(needing) == 1 else "repositories"
    raise StepError(
        STEP,
        f"{what} {listed} cloned over SSH, but there is no `ssh` command here: install "
        "openssh-client (docker-ros installs it by itself in image builds)",
    )


def _multiline(value: str) -> str:
    """Keys given in one line with literal `\\n` (docker-ros used `echo -e`) become real lines."""
    if "\n" not in value and "\\n" in value:
        value = value.replace("\\n", "\n")
    return value if value.endswith("\n") else value + "\n"


def _private_file(directory: str, name: str, content: str) -> str:
    path = os.path.join(directory, name)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as handle:
        handle.write(content)
    return path


@contextlib.contextmanager
def git_credentials(
    settings: Settings, *, secrets_dir: Optional[Path] = None
) -> Iterator[Dict[str, str]]:
    """Environment additions that let git authenticate, valid while the context is open.
    Secrets not in the settings are read from BuildKit secret files in `secrets_dir`."""
    secrets_dir = SECRETS_DIR if secrets_dir is None else secrets_dir
    server = read_secret(settings, "git_https_server", secrets_dir)
    user = read_secret(settings, "git_https_user", secrets_dir)
    password = read_secret(settings, "git_https_password", secrets_dir)
    key = read_secret(settings, "git_ssh_private_key", secrets_dir)
    known_hosts = read_secret(settings, "git_ssh_known_host_keys", secrets_dir)
    env: Dict[str, str] = {}
    if not ((server and password) or key):
        yield env
        return
    tmp = tempfile.mkdtemp(prefix="docker-ros-git-")  # mode 0700
    try:
        if server and password:
            host = server_host(server)
            askpass = _private_file(tmp, "askpass.sh", ASKPASS_SCRIPT)
            os.chmod(askpass, stat.S_IRWXU)
            env.update(
                GIT_ASKPASS=askpass,
                DOCKER_ROS_GIT_HTTPS_HOST=host,
                DOCKER_ROS_GIT_HTTPS_USER=user or "",
                DOCKER_ROS_GIT_HTTPS_PASSWORD=password,
                **no_credential_helper(os.environ),
            )
            LOG.info("%s: HTTPS credentials for %s in use", STEP, host)
        if key:
            if not shutil.which("ssh"):
                LOG.warning("%s: GIT_SSH_PRIVATE_KEY is set, but there is no `ssh` command: "
                            "SSH URLs cannot be cloned (install openssh-client)", STEP)
            key_file = _private_file(tmp, "id", _multiline(key))
            command = ["ssh", "-i", key_file, "-o", "IdentitiesOnly=yes"]
            if known_hosts:
                hosts_file = _private_file(tmp, "known_hosts", _multiline(known_hosts))
                user_hosts = os.path.expanduser("~/.ssh/known_hosts")
                command += ["-o", f"UserKnownHostsFile={hosts_file} {user_hosts}"]
            env["GIT_SSH_COMMAND"] = format_argv(command)
            LOG.info("%s: SSH private key in use", STEP)
        yield env
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def no_credential_helper(environ: Mapping[str, str]) -> Dict[str, str]:
    """git configuration by environment that empties the credential helper list for our
    clones: a user's helper (store, a keychain) would otherwise save the password git got from
    our askpass. GIT_CONFIG_PARAMETERS (what `git -c` hands to git's children) is read by every
    git in use (GIT_CONFIG_COUNT needs git >= 2.31: Ubuntu 20.04 has 2.25); added after the
    entries the environment has."""
    existing = environ.get("GIT_CONFIG_PARAMETERS", "")
    return {"GIT_CONFIG_PARAMETERS": f"{existing} 'credential.helper='".lstrip()}


# --- the step ---


def hook_argv(script: Path) -> List[str]:
    """How docker-ros ran this hook (`chmod +x` and execute it): by its `#!` line's interpreter
    (and its one optional argument, as the kernel reads it), else with bash. The script's mode
    is left alone (on the host it is a file of the repository)."""
    first = script.read_bytes().split(b"\n", 1)[0]
    if first.startswith(b"#!"):
        interpreter, _, argument = first[2:].decode("utf-8", "replace").strip().partition(" ")
        if interpreter:
            return [interpreter, *([argument.strip()] if argument.strip() else []), str(script)]
    return ["bash", str(script)]


def run_hook(ws: Workspace, settings: Settings, *, dry_run: bool) -> None:
    script = repository_path(ws, settings, "before_dependency_identification_script", step=STEP)
    if not script.is_file():
        LOG.info(
            "%s: no %s, no hook to run", STEP, settings.before_dependency_identification_script
        )
        return
    # In an image, what the hook changes in the system is kept for the resolve and install
    # stages (runtime.system), as in docker-ros, where the hook and the installs share a stage.
    in_image = hook_context() == "image" and not dry_run
    since = system.mark()
    run_script(hook_argv(script), script, step=STEP, dry_run=dry_run, cwd=ws.root,
               what=str(script))
    if in_image:
        system.report(STEP, system.capture(since))


def import_argv(repos_file: Path, dest: Path, *, skip_existing: bool) -> List[str]:
    argv = ["vcs", "import", "--recursive", "--input", str(repos_file), str(dest)]
    return argv + (["--skip-existing"] if skip_existing else [])


def candidates(ws: Workspace, settings: Settings, *, required: bool = True) -> List[Path]:
    return find_special_files(ws, settings, "vcs_import_file", pattern="*.repos", step=STEP,
                              required=required)


def import_file(
    ws: Workspace,
    repos_file: Path,
    repos: Mapping[str, Mapping[str, str]],
    *,
    skip_existing: bool,
    env: Mapping[str, str],
) -> None:
    """One `vcs import`; on failure, the repositories it created are removed (so a re-run
    clones them again) and the error names each failed repository with vcstool's reason."""
    require_ssh(repos, env)
    names = sorted(repos)
    existed = {name for name in names if (ws.upstream / name).exists()}
    argv = import_argv(repos_file, ws.upstream, skip_existing=skip_existing)
    # Never wait for a password on a terminal (builds have none; vcs runs clones in parallel).
    full_env = {**os.environ, "GIT_TERMINAL_PROMPT": "0", **env}
    # (vcstool prints a failed clone's URL as written: with a password in it, too)
    returncode, lines = run_tee(argv, step=STEP, cwd=ws.root, env=full_env,
                                shown=hide_url_passwords)
    if returncode == 0:
        return
    blocks = vcs_blocks(lines, ws.upstream, names)
    failures = block_failures(blocks)
    doomed = [n for n in names if n not in existed and (n in failures or not failures)]
    for name in doomed:
        remove_tree(ws.upstream / name, step=STEP, dry_run=False)
    if failures:
        detail = "; ".join(
            f"repository '{name}' ({hide_url_passwords(repos[name].get('url', '?'))}"
            + (f" @ {repos[name]['version']}" if repos[name].get("version") else "")
            + f"): {reason}"
            + failure_hint(repos[name].get("url", ""), reason,
                           in_image=os.environ.get("DOCKER_ROS") == "1")
            + login_hint(repos[name].get("url", ""), blocks.get(name, []), env)
            for name, reason in sorted(failures.items())
        )
    else:
        tail = [line for line in lines if line.strip()][-3:]
        detail = " / ".join(tail) or "no output"
    raise StepError(
        STEP, f"vcs import of {repos_file} failed (exit code {returncode}): {detail}", returncode
    )


def main(
    ws: Workspace,
    settings: Settings,
    *,
    phase: str = "all",
    dry_run: bool = False,
    **options: object,
) -> None:
    """Single phase: the hook, then every .repos file, each imported once. Option
    imports_only (the image's upstream stage, which holds the .repos files alone): no hook, and
    an explicitly set VCS_IMPORT_FILE may be missing (the full run after it checks)."""
    phases(STEP, phase)
    imports_only = bool(options.get("imports_only"))
    with step_log(STEP):
        ws.require_sources(STEP)
        if not imports_only:
            run_hook(ws, settings, dry_run=dry_run)
        state = ws.read_state(STATE_FILE) or {}
        imported: Dict[str, Any] = (
            dict(state.get("imported") or {}) if isinstance(state, dict) else {}
        )
        if dry_run:
            dry(STEP, f"create {ws.upstream}")
        else:
            ws.upstream.mkdir(parents=True, exist_ok=True)
        seen_paths: Set[str] = set()
        done_hashes: Set[str] = set()
        entry = active_entry(ws, settings, STEP)
        locked = dict(entry.get("repos") or {}) if entry is not None else None
        with git_credentials(settings) as env:
            for _round in range(MAX_ROUNDS):
                new = []
                for repos_file in candidates(ws, settings, required=not imports_only):
                    real = os.path.realpath(str(repos_file))
                    if real in seen_paths:
                        continue
                    seen_paths.add(real)
                    new.append(repos_file)
                if not new:
                    break
                for repos_file in new:
                    _import_once(ws, repos_file, imported, done_hashes, env, dry_run=dry_run,
                                 locked=locked)
                if not settings.enable_recursive_vcs_import or dry_run:
                    break
            else:
                raise StepError(
                    STEP, f"still finding new .repos files after {MAX_ROUNDS} rounds: giving up"
                )
        if not seen_paths:
            LOG.info("%s: no .repos files, nothing to import", STEP)
        if not dry_run:  # the record of what is imported, also when nothing is
            ws.write_state(STATE_FILE, {"imported": imported})


def _import_once(
    ws: Workspace,
    repos_file: Path,
    imported: Dict[str, Any],
    done_hashes: Set[str],
    env: Mapping[str, str],
    *,
    dry_run: bool,
    locked: Optional[Mapping[str, Mapping[str, str]]] = None,
) -> None:
    rel = ws.relative(repos_file)
    digest = file_sha256(repos_file)
    repos = read_repos(repos_file, step=STEP, shown=rel)
    record = imported.get(rel) or {}
    if digest in done_hashes:
        LOG.info("%s: %s has the content of a file already imported, skipped", STEP, rel)
        return
    done_hashes.add(digest)
    if not repos:
        LOG.info("%s: %s lists no repositories, skipped", STEP, rel)
        if not dry_run:
            imported[rel] = {"repositories": [], "sha256": digest}
            ws.write_state(STATE_FILE, {"imported": imported})
        return
    if record.get("sha256") == digest and all(
        (ws.upstream / name).exists() for name in record.get("repositories", [])
    ):
        LOG.info("%s: %s already imported, skipped", STEP, rel)
        return
    # A file changed since its last import updates existing checkouts to its versions;
    # otherwise the first file naming a repository wins (the repository's own .repos first).
    changed = bool(record) and record.get("sha256") != digest
    if dry_run:
        run(
            import_argv(repos_file, ws.upstream, skip_existing=not changed),
            step=STEP,
            dry_run=True,
            cwd=ws.root,
        )
        return
    LOG.info("%s: importing %d repositories from %s", STEP, len(repos), rel)
    if locked is not None:  # LOCKED: the commits of docker-ros.lock
        repos_file = pinned_repos_file(ws, STEP, repos_file, repos, locked)
        repos = read_repos(repos_file, step=STEP)
    import_file(ws, repos_file, repos, skip_existing=not changed, env=env)
    imported[rel] = {"repositories": sorted(repos), "sha256": digest}
    ws.write_state(STATE_FILE, {"imported": imported})
