"""docker-ros's CI tag rules: which pipeline we run in, and what that does to image tags.

Standard library only: loading.py derives the settings defaults from here, and both ship into
images.
"""

from __future__ import annotations

import json
import re
import unicodedata
from dataclasses import dataclass
from pathlib import Path
from typing import Collection, List, Mapping, Optional, Sequence, Tuple

# IMAGE_POSTFIX value that switches the derived postfix off ("" would count as unset).
NO_POSTFIX = "none"
SLUG_MAX = 63  # GitLab's CI_COMMIT_REF_SLUG length
# The GitHub Action's slug of the branch (gacts/github-slug@v1's output, as docker-ros's action)
REF_SLUG = "DOCKER_ROS_REF_SLUG"


@dataclass(frozen=True)
class Pipeline:
    """Where a CI pipeline runs: which ref, of which kind, and the repository's default branch."""

    ci: str  # "github" or "gitlab"
    kind: str  # "branch", "tag" or "merge_request" (GitHub: pull request)
    ref: str  # branch or tag name; the source branch of a merge/pull request
    default_branch: str  # "" when the CI does not tell
    slug: str = ""  # the CI's own slug of ref (the GitHub Action's slug step); "" to make it

    @property
    def on_default_branch(self) -> bool:
        return self.kind == "branch" and bool(self.default_branch) and (
            self.ref == self.default_branch
        )


def slugify(name: str) -> str:
    """GitLab's CI_COMMIT_REF_SLUG: lower case, 63 bytes, all but [0-9a-z] as `-` (a run of
    them stays a run), no `-` at the ends. Made here, not read: the same on GitLab, and
    gitlab-ci-local, which sets its own (runs made one `-`), then names tags as GitLab does."""
    slug = re.sub(r"[^0-9a-z]", "-", name.lower())[:SLUG_MAX]
    return slug.strip("-")


# Symbols the npm `slugify` package (behind gacts/github-slug) spells as words.
SLUG_WORDS = {"$": "dollar", "%": "percent", "&": "and", "<": "less", ">": "greater", "|": "or"}


def github_slug(name: str) -> str:
    """The slug of gacts/github-slug@v1, which docker-ros's action puts in its CI tags, for
    `docker-ros ci` run outside the Action (which runs that action itself): `._/()#+-` and
    white space separate words, a few symbols become words, other characters are dropped
    (accents first lose their mark; letters of other scripts and ß, æ, ø... are dropped too,
    where the action transliterates them), words joined by one `-`, lower case."""
    text = unicodedata.normalize("NFKD", name)
    text = "".join(SLUG_WORDS.get(ch, ch) for ch in text if not unicodedata.combining(ch))
    words = re.sub(r"[^A-Za-z0-9\s]", "", re.sub(r"[-._/()#+]", " ", text)).split()
    return "-".join(words).lower()


def ref_slug(pipeline: Pipeline) -> str:
    """The branch slug as docker-ros's pipeline of that CI spells it: the one the Action's slug
    step made (gacts/github-slug, as docker-ros's; it transliterates every script), else ours."""
    if pipeline.slug:
        return pipeline.slug
    return github_slug(pipeline.ref) if pipeline.ci == "github" else slugify(pipeline.ref)


def docker_tag_part(name: str) -> str:
    """A git tag as part of a Docker tag (allowed: [A-Za-z0-9_.-]; `v1.2` stays `v1.2`)."""
    return re.sub(r"[^A-Za-z0-9_.-]", "-", name)


def detect_pipeline(environ: Mapping[str, str]) -> Optional[Pipeline]:
    """The GitHub Actions or GitLab CI pipeline described by environ; None outside CI."""
    if environ.get("GITHUB_ACTIONS") == "true":
        default = environ.get("GITHUB_DEFAULT_BRANCH", "")
        slug = environ.get(REF_SLUG, "")
        if environ.get("GITHUB_HEAD_REF"):  # pull_request events: the source branch
            return Pipeline("github", "merge_request", environ["GITHUB_HEAD_REF"], default, slug)
        kind = "tag" if environ.get("GITHUB_REF_TYPE") == "tag" else "branch"
        return Pipeline("github", kind, environ.get("GITHUB_REF_NAME", ""), default, slug)
    if environ.get("GITLAB_CI") == "true":
        default = environ.get("CI_DEFAULT_BRANCH", "")
        if environ.get("CI_COMMIT_TAG"):
            return Pipeline("gitlab", "tag", environ["CI_COMMIT_TAG"], default)
        if environ.get("CI_MERGE_REQUEST_SOURCE_BRANCH_NAME"):
            source = environ["CI_MERGE_REQUEST_SOURCE_BRANCH_NAME"]
            return Pipeline("gitlab", "merge_request", source, default)
        branch = environ.get("CI_COMMIT_BRANCH") or environ.get("CI_COMMIT_REF_NAME", "")
        return Pipeline("gitlab", "branch", branch, default)
    return None


def tag_postfix(pipeline: Optional[Pipeline]) -> str:
    """Appended to every image tag: `_<slug>_ci` off the default branch (docker-ros), the git
    tag as `-<tag>` in tag pipelines (docker-ros's GitLab "target tag"), else nothing. An
    unknown default branch counts as another branch: a CI image never overwrites a release."""
    if pipeline is None or pipeline.on_default_branch:
        return ""
    if pipeline.kind == "tag":
        return "-" + docker_tag_part(pipeline.ref)
    return f"_{ref_slug(pipeline)}_ci"


def push_also_as(
    pipeline: Optional[Pipeline], *, image_tag: str, enable_push_as_latest: bool,
    postfix: str = "",
) -> Tuple[str, ...]:
    """Tags pushed besides the configured ones (run: `<t>`, dev: `<t>-dev`, slim: `<t>-slim`;
    a tag ending in postfix, IMAGE_POSTFIX: `<t>-dev<postfix>`...).

    ENABLE_PUSH_AS_LATEST pushes `latest` outside CI and on the default branch; off it, on
    GitHub, `latest<postfix>` (docker-ros's action pushes its "as latest" names on every branch,
    its GitLab template from the default branch only). A tag pipeline pushes the git tag itself
    when IMAGE_TAG is `latest` or ENABLE_PUSH_AS_LATEST is set (docker-ros's GitLab "Push
    latest" and "Push tag" jobs)."""
    if pipeline is not None and pipeline.kind == "tag":
        if enable_push_as_latest or image_tag == "latest":
            return (docker_tag_part(pipeline.ref),)
        return ()
    if not enable_push_as_latest:
        return ()
    if pipeline is None or pipeline.on_default_branch:
        return ("latest",)
    # (no postfix there, IMAGE_POSTFIX=none: `latest` would overwrite the default branch's)
    return (f"latest{postfix}",) if pipeline.ci == "github" and postfix else ()


def github_default_branch(environ: Mapping[str, str]) -> str:
    """The default branch from the GitHub event payload (GITHUB_EVENT_PATH), "" if unknown."""
    path = environ.get("GITHUB_EVENT_PATH")
    if environ.get("GITHUB_ACTIONS") != "true" or not path:
        return ""
    try:
        event = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return ""
    repository = event.get("repository") if isinstance(event, dict) else None
    branch = repository.get("default_branch") if isinstance(repository, dict) else None
    return branch if isinstance(branch, str) else ""


def error_annotation(environ: Mapping[str, str], title: str, message: str) -> str:
    """A failed task's message as a GitHub Actions error annotation (`::error title=...::...`,
    shown on the run's summary page, where otherwise only `exit code 1` is); '' elsewhere."""
    if environ.get("GITHUB_ACTIONS") != "true":
        return ""

    def escaped(text: str, extra: str = "") -> str:
        for char, code in (("%", "%25"), ("\r", "%0D"), ("\n", "%0A"), *(
                (c, f"%{ord(c):02X}") for c in extra)):
            text = text.replace(char, code)
        return text

    return f"::error title={escaped(title, ':,')}::{escaped(message)}"


# Tasks a CI job may need that not every docker-ros has, and the setting that asks for them.
OPTIONAL_TASKS = {"test": "ENABLE_INDUSTRIAL_CI", "slim": "ENABLE_SLIM"}
# The build before test/slim leaves both to the explicit calls that follow it.
SEPARATE = ("--set", "ENABLE_SLIM=false", "--set", "ENABLE_INDUSTRIAL_CI=false")


def plan_ci_job(
    *, target: Tuple[str, ...], enable_industrial_ci: bool, enable_slim: bool,
    slims_here: bool = True,
) -> List[List[str]]:
    """The docker-ros tasks (argv after `docker-ros`) of one CI job: build, test, slim, push.
    Tests run before anything is pushed, so a failing test pushes nothing. A `slim` target is
    the slim task's: the build makes the images without it. ENABLE_SLIM on a runner that can
    slim none of the platforms (slims_here false: slimming runs the image, and docker-ros
    slims a job's foreign architecture in a job of its own, on a runner of that architecture)
    slims and pushes no slim image; a `slim` target asked for it, and slim says why it cannot."""
    images = [t for t in target if t != "slim"]
    plan = [["build", *SEPARATE, *(["--target", ",".join(images)] if "slim" in target else [])]]
    if enable_industrial_ci:
        plan.append(["test"])
    slim = enable_slim and "run" in target  # (a slim target sets ENABLE_SLIM)
    if slim and (slims_here or "slim" in target):
        plan.append(["slim"])
    plan.append(["push", "--set", "ENABLE_INDUSTRIAL_CI=false",
                 *(["--set", "ENABLE_SLIM=false"] if slim and ["slim"] not in plan else [])])
    return plan


def slim_skipped(platforms: Sequence[str], host: str) -> str:
    """What a CI job says when ENABLE_SLIM slims nothing on this runner (plan_ci_job)."""
    names = "/".join(platforms)
    return (f"slim: {names} not slimmed on this {host} runner (slimming runs the image): a slim "
            f"{names} image needs a job on a runner of that architecture; ENABLE_SLIM=false "
            "leaves it out without this note")


def missing_tasks(plan: Sequence[Sequence[str]], available: Collection[str]) -> List[str]:
    """One line per task of the plan that this docker-ros does not have, with what to do."""
    return [
        f"{OPTIONAL_TASKS.get(argv[0], argv[0])}=true needs the `{argv[0]}` task, which this "
        f"docker-ros does not have yet: set {OPTIONAL_TASKS.get(argv[0], argv[0])}=false"
        for argv in plan
        if argv[0] not in available
    ]


# docker-ros's GitLab template's 21 names of the images (its global `_*IMAGE*` variables), which
# jobs of a .gitlab-ci.yml use; the template's pushing jobs give them as a dotenv report.
IMAGE_KINDS = {"RUN": "", "DEV": "-dev", "SLIM": "-slim"}


def image_references(
    images: Mapping[str, Tuple[str, str]], postfix: str, git_tag: str
) -> List[Tuple[str, str]]:
    """docker-ros's `_RUN_IMAGE`, `_IMAGE_RUN_CI`, `_IMAGE_RUN_CI_AMD64`... for this pipeline's
    images: images maps RUN, DEV and SLIM to (name, tag as pushed, IMAGE_POSTFIX included).
    `_<KIND>_IMAGE` is the configured name (no postfix), `_IMAGE_<KIND>_CI` the name this
    pipeline's Push job writes and `_IMAGE_<KIND>_CI_<ARCH>` the build job's (docker-ros's roles;
    on the default branch these carry no `_<slug>_ci`, as the images here), `_IMAGE_<KIND>_LATEST`
    the `latest` name, `_IMAGE_<KIND>_TARGET_TAG` and `_IMAGE_<KIND>_TAG` the names of a tag
    pipeline (`<IMAGE_TAG>-<git tag>`, `<git tag>`; empty in other pipelines)."""
    plain = {kind: (name, tag[: -len(postfix)] if postfix and tag.endswith(postfix) else tag)
             for kind, (name, tag) in images.items()}
    out = [(f"_{kind}_IMAGE", f"{plain[kind][0]}:{plain[kind][1]}") for kind in IMAGE_KINDS]
    for kind, suffix in IMAGE_KINDS.items():
        name, tag = images[kind]
        out += [(f"_IMAGE_{kind}_CI", f"{name}:{tag}"),
                (f"_IMAGE_{kind}_CI_AMD64", f"{name}:{tag}-amd64"),
                (f"_IMAGE_{kind}_CI_ARM64", f"{name}:{tag}-arm64"),
                (f"_IMAGE_{kind}_LATEST", f"{name}:latest{suffix}"),
                (f"_IMAGE_{kind}_TARGET_TAG",
                 f"{name}:{plain[kind][1]}-{git_tag}" if git_tag else ""),
                (f"_IMAGE_{kind}_TAG", f"{name}:{git_tag}{suffix}" if git_tag else "")]
    return out


def build_state_references(states: Mapping[str, str],
                           pushed: Collection[str]) -> List[Tuple[str, str]]:
    """`_IMAGE_BUILD_STATE_CI_<ARCH>` for the build states (platform -> name) this job pushed:
    ours, not docker-ros's, and only when pushed (a run-only pipeline pushes none unless
    BUILD_STATE_REPOSITORY is set)."""
    return [(f"_IMAGE_BUILD_STATE_CI_{platform.upper()}", name)
            for platform, name in states.items() if name in pushed]


def digest_references(references: Sequence[Tuple[str, str]],
                      pushed: Mapping[str, str]) -> List[Tuple[str, str]]:
    """`<variable>_DIGEST` for each image reference variable (image_references,
    build_state_references) whose name this job pushed: the registry digest its push gave (a
    manifest list's for the Push jobs' names). None for a name it did not push or whose digest
    is unknown: an empty one in a build job's report would blank the Push job's in a later job
    that needs both."""
    return [(f"{variable}_DIGEST", pushed[name])
            for variable, name in references if name and pushed.get(name)]
