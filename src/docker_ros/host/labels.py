"""The labels of the dev, run and slim images: the OCI ones (`org.opencontainers.image.*`) from
the repository's git and package.xml files, and the user's LABELS.

They reach the build as `--label` (bake: `labels`), which BuildKit writes into the final
image's configuration only: no RUN step's cache key holds them. `created` is the commit's time
(SOURCE_DATE_EPOCH when set), not the clock's: a rebuild of the same commit gives the same image
(ID), so a no-change build leaves no untagged image behind and slim's "up to date" still holds.
"""

from __future__ import annotations

import datetime
import os
import re
import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Mapping, Optional, Sequence, Tuple
from urllib.parse import urlsplit, urlunsplit
from xml.etree import ElementTree

from docker_ros.core.labels import parse_labels
from docker_ros.core.settings import Settings
from docker_ros.in_image.runtime.packages import find_package_dirs

OCI = "org.opencontainers.image"
# the targets that are images of the user's (build-state, test-results, lock stages: ours)
LABELLED = ("dev", "run", "slim")


@dataclass(frozen=True)
class GitFacts:
    """What the repository's git says: HEAD's commit, its commit time (seconds since the epoch,
    0 unknown) and the URL of its remote ('' none)."""

    revision: str = ""
    committed: int = 0
    remote: str = ""


def git_facts(repository: Path) -> GitFacts:
    """GitFacts of the repository holding the build context (empty outside git, or without
    git)."""
    def git(*args: str) -> str:
        try:
            proc = subprocess.run(["git", "-C", str(repository), *args], capture_output=True,
                                  text=True, timeout=30)
        except (OSError, subprocess.SubprocessError):
            return ""
        return proc.stdout.strip() if proc.returncode == 0 else ""

    head = git("log", "-1", "--format=%H %ct")
    if not head:
        return GitFacts()
    revision, _, committed = head.partition(" ")
    remotes = git("remote").split()
    remote = "origin" if "origin" in remotes else (remotes[0] if remotes else "")
    url = git("remote", "get-url", remote) if remote else ""
    return GitFacts(revision, int(committed) if committed.isdigit() else 0, url)


SCP_LIKE = re.compile(r"^(?:[\w.-]+@)?([\w.-]+):(?!//)(.+)$")  # git@host:owner/repo.git


def web_url(remote: str) -> str:
    """A git remote as the repository's https URL, without credentials (`https://user:token@`,
    GitLab's `gitlab-ci-token:...@`), query or `.git`; '' for a local path."""
    remote = remote.strip()
    scp = SCP_LIKE.match(remote)
    if scp and "/" not in scp.group(1):
        remote = f"https://{scp.group(1)}/{scp.group(2)}"
    parts = urlsplit(remote)
    if parts.scheme not in ("https", "http", "ssh", "git") or not parts.hostname:
        return ""
    host = parts.hostname + (f":{parts.port}" if parts.port and parts.scheme in ("https", "http")
                             else "")
    path = re.sub(r"\.git/?$", "", parts.path).rstrip("/")
    scheme = parts.scheme if parts.scheme in ("https", "http") else "https"
    return urlunsplit((scheme, host, path, "", ""))


def source_url(remote: str, environ: Mapping[str, str]) -> str:
    """org.opencontainers.image.source: the CI's own name of the repository (GitHub's server
    and repository, GitLab's project URL), else the git remote's (web_url)."""
    if environ.get("GITHUB_SERVER_URL") and environ.get("GITHUB_REPOSITORY"):
        return f"{environ['GITHUB_SERVER_URL'].rstrip('/')}/{environ['GITHUB_REPOSITORY']}"
    if environ.get("CI_PROJECT_URL"):
        return web_url(environ["CI_PROJECT_URL"])
    return web_url(remote)


def created_time(committed: int, environ: Mapping[str, str]) -> str:
    """org.opencontainers.image.created (RFC 3339, UTC): SOURCE_DATE_EPOCH when set (the
    reproducible-builds variable), else the commit's time; '' when neither is known."""
    epoch = environ.get("SOURCE_DATE_EPOCH", "").strip()
    if not epoch.isdigit() and not committed:
        return ""
    seconds = int(epoch) if epoch.isdigit() else committed
    moment = datetime.datetime.fromtimestamp(seconds, tz=datetime.timezone.utc)
    return moment.strftime("%Y-%m-%dT%H:%M:%SZ")


def package_licenses(repository: Path) -> List[Tuple[str, ...]]:
    """The `<license>` entries of each package.xml of the repository (as colcon finds the
    packages); a manifest that cannot be read counts as one without."""
    found: List[Tuple[str, ...]] = []
    for directory in find_package_dirs(repository):
        try:
            root = ElementTree.parse(str(directory / "package.xml")).getroot()
        except (ElementTree.ParseError, OSError):
            found.append(())
            continue
        found.append(tuple((e.text or "").strip() for e in root.findall("license")
                           if (e.text or "").strip()))
    return found


def agreed_license(licenses: Sequence[Tuple[str, ...]]) -> str:
    """org.opencontainers.image.licenses: the license every package names alike (several
    `<license>` tags of one package: joined by ` AND `, as SPDX writes that); '' when there is
    no package, one names none, or they differ."""
    kinds = {tuple(sorted(set(each))) for each in licenses}
    if len(kinds) != 1:
        return ""
    (agreed,) = kinds
    return " AND ".join(agreed)


def title(settings: Settings, target: str) -> str:
    """org.opencontainers.image.title: the image's name without registry and path; dev and
    slim say which they are."""
    field = "image_name" if target == "run" else f"{target}_image_name"
    name = str(getattr(settings, field) or settings.image_name or "").rsplit("/", 1)[-1]
    return name if target == "run" else f"{name} ({target})"


def image_labels(settings: Settings, target: str, facts: GitFacts, licenses: str,
                 environ: Mapping[str, str]) -> Dict[str, str]:
    """The labels of a dev, run or slim image: the OCI ones that are known, then LABELS (which
    win); none for the other targets."""
    if target not in LABELLED:
        return {}
    oci = {
        "source": source_url(facts.remote, environ),
        "revision": facts.revision,
        "created": created_time(facts.committed, environ),
        "version": settings.image_tag,
        "title": title(settings, target),
        "licenses": licenses,
    }
    labels = {f"{OCI}.{key}": value for key, value in oci.items() if value}
    labels.update(parse_labels(settings.labels))
    return labels


def build_labels(settings: Settings, environ: Optional[Mapping[str, str]] = None
                 ) -> Dict[str, Dict[str, str]]:
    """image_labels of every labelled target, read from the build context's git and
    package.xml files once."""
    environ = os.environ if environ is None else environ
    repository = Path(settings.build_context).expanduser()
    facts = git_facts(repository)
    licenses = agreed_license(package_licenses(repository))
    return {t: image_labels(settings, t, facts, licenses, environ) for t in LABELLED}
