"""What a build reads besides the repository: the tools and imports images, the staged
Dockerfile, the CA bundle."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import stat
import subprocess
import tempfile
from pathlib import Path
from typing import Dict, Iterable, List, Mapping, Optional, Sequence

import docker_ros
from docker_ros.core.errors import BuildError
from docker_ros.core.labels import ours
from docker_ros.core.settings import Settings
from docker_ros.host import engine
from docker_ros.host.engine import image_exists
from docker_ros.in_image.runtime.files import walk
from docker_ros.in_image.runtime.inputs import resolve_inputs
from docker_ros.in_image.runtime.lockfile import LOCK_FILE
from docker_ros.in_image.runtime.workspace import StepError, Workspace

PACKAGE_DIR = Path(docker_ros.__file__).resolve().parent
DOCKERFILE = PACKAGE_DIR / "docker" / "Dockerfile"
TOOLS_REPOSITORY = "docker-ros-tools"
IMPORTS_REPOSITORY = "docker-ros-imports"
IMPORTS_LABEL = ours("imports-of")  # the repository (imports_owner) that made the image
# the dev image's: the content digest of the files resolving its dependencies read (the
# imports image's), which `inv dev-shell` compares with the repository's (stale_dev_image)
INPUTS_LABEL = ours("dependency-inputs")
# the names of these labels before one namespace, on images of an earlier version
OLD_LABELS = {IMPORTS_LABEL: "docker-ros.imports-of",
              INPUTS_LABEL: "io.github.docker-ros.dependency-inputs"}
# Files of the package that the images need (stdlib-only step modules and the image scripts).
TOOLS_PATTERNS = ("__init__.py", "core/*.py", "in_image/*.py", "in_image/*/*.py", "docker/*.sh")
SCRATCH_FOLDER = ".gitlab-ci-local"  # gitlab-ci-local's copies of the repository
# Names that never reach an image, wherever they are in the repository (see dockerignore);
# the last two, the GitLab template's copy of the tests' results and its dotenv report of the
# image names, are artifacts of an earlier job.
LEFT_OUT = (".env", ".git", ".gitlab-ci-local-variables.yml", "docker-ros-test-results",
            "docker-ros-images.env")
BUILDX = ("docker", "buildx")  # the command reaching the default builder


def _kept(lines: List[str], line: str) -> str:
    lines.append(line)
    return line


def tools_tree(destination: Path) -> str:
    """Copy the in-image modules to destination/docker-ros/lib; return their content hash."""
    digest = hashlib.sha256()
    lib = destination / "docker-ros" / "lib" / "docker_ros"
    for pattern in TOOLS_PATTERNS:
        for path in sorted(PACKAGE_DIR.glob(pattern)):
            rel = path.relative_to(PACKAGE_DIR)
            digest.update(str(rel).encode() + b"\0" + path.read_bytes() + b"\0")
            (lib / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(path, lib / rel)
            if path.suffix == ".sh":  # a wheel install may not keep the executable bit
                (lib / rel).chmod(0o755)
    return digest.hexdigest()[:16]


def dockerignore(context: Path, also: Sequence[str] = ()) -> str:
    """The user's .dockerignore plus ours: what may hold credentials stays out of every image
    (`.env` files; git's folders, whose config may carry a CI job token or a checkout's
    authorization header; gitlab-ci-local's variables file), and so do gitlab-ci-local's
    scratch folder (copies of the repository made inside it) and the CI template's test
    results (left in a checkout a shell runner reuses). A build reads none of them. also: more
    patterns of ours (additional_files_pattern)."""
    user = context / ".dockerignore"
    lines = user.read_text().splitlines() if user.is_file() else []
    ours = ["# added by docker-ros", *[f"{w}{name}" for name in LEFT_OUT for w in ("", "**/")],
            SCRATCH_FOLDER, *also]
    return "\n".join([*lines, *ours]) + "\n"


def left_out(rel: str) -> bool:
    """Whether our own .dockerignore lines (dockerignore) leave the relative path out."""
    parts = rel.split("/")
    return any(part in LEFT_OUT for part in parts) or parts[0] == SCRATCH_FOLDER


def stage_dockerfile(context: Path, destination: Path, also_left_out: Sequence[str] = ()) -> Path:
    """Our Dockerfile beside a Dockerfile.dockerignore (BuildKit reads it instead of the
    context's .dockerignore), so the user's repository is never modified."""
    dockerfile = destination / "Dockerfile"
    dockerfile.write_text(DOCKERFILE.read_text())
    (destination / "Dockerfile.dockerignore").write_text(dockerignore(context, also_left_out))
    return dockerfile


def ensure_tools_image(platform: str, buildx: Sequence[str] = BUILDX,
                       layouts: Optional[Path] = None) -> str:
    """A FROM-scratch image with the step modules, tagged by their content hash (one per
    docker-ros version that built here, shared by every repository: never removed by us).
    layouts: made as an OCI layout there instead (see scratch_image)."""
    with tempfile.TemporaryDirectory(prefix="docker-ros-tools-") as tmp:
        digest = tools_tree(Path(tmp))
        return scratch_image(Path(tmp), "docker-ros", f"{TOOLS_REPOSITORY}:{digest}-{platform}",
                             platform, buildx=buildx, layouts=layouts)


# The time every file of a scratch image has (SOURCE_DATE_EPOCH's usual value)
SCRATCH_MTIME = 0


def reproducible(folder: Path) -> None:
    """Give every file and folder under folder (itself too) the same time, and modes as git
    keeps them (755 for folders and executables, else 644), so that the same content makes
    the same image layer on any machine. A pip install or a temporary copy gives files the
    time they were written, so each CI runner made a tools image of other layers (measured:
    two installs of one wheel, two layer digests), and BuildKit's key for a FROM of it (the
    layers' chain) could then match no registry cache record of another runner's build."""
    for path in sorted(folder.rglob("*"), reverse=True) + [folder]:
        if not path.is_symlink():
            executable = path.is_dir() or path.stat().st_mode & 0o100
            path.chmod(0o755 if executable else 0o644)
        os.utime(path, (SCRATCH_MTIME, SCRATCH_MTIME), follow_symlinks=False)


def scratch_image(context: Path, folder: str, ref: str, platform: str, into: str = "",
                  buildx: Sequence[str] = BUILDX, labels: Mapping[str, str] = {},
                  layouts: Optional[Path] = None) -> str:
    """ref: FROM scratch with context/folder at /folder (or its contents at into), built
    (on the builder of the build, where its FROM finds it) unless it exists already.
    layouts: a builder with a BuildKit of its own (docker-container, remote) has no image
    store, so a FROM of ref would look for it on Docker Hub: it is exported as an OCI layout
    under layouts instead, which the build gets as a named context (scratch_layout)."""
    if layouts is None and image_exists(ref):
        return ref
    (context / "Dockerfile").write_text(f"FROM scratch\nCOPY {folder} {into or '/' + folder}\n")
    reproducible(context / folder)
    # The same content makes the same image, digest included (the containerd store keys a FROM
    # by it): fixed times (SOURCE_DATE_EPOCH, Engine 26's BuildKit; 20.10 keys by the layers)
    # and no provenance. So it is made afresh (--no-cache): a cache record of an earlier image
    # of this content whose layer went with that image (a superseded imports image removed,
    # then the cache pruned in part) failed the build ("layer does not exist", Engine 20.10).
    output = (["--output", f"type=oci,tar=false,dest={layout_folder(layouts, ref)}"]
              if layouts is not None else ["--load"])
    argv = [*buildx, "build", "--quiet", *output, "--no-cache", "--provenance=false",
            "--build-arg", "SOURCE_DATE_EPOCH=0", "--platform", f"linux/{platform}",
            *[a for k, v in labels.items() for a in ("--label", f"{k}={v}")],
            "--tag", ref, str(context)]
    proc = subprocess.run(argv, capture_output=True, text=True)
    if proc.returncode != 0:
        raise BuildError(f"building {ref} failed: {proc.stderr.strip()}")
    return ref


def layout_folder(layouts: Path, ref: str) -> Path:
    """Where scratch_image puts ref's OCI layout under layouts (a folder per image)."""
    return layouts / ref.replace("/", "_").replace(":", "_")


def scratch_layout(layouts: Path, ref: str) -> str:
    """The named build context standing for ref (pinned to the image scratch_image exported
    there): `FROM ref` then reads that image, with the same digest an image store would give
    it, so cache keys stay those of a loaded image."""
    index = json.loads((layout_folder(layouts, ref) / "index.json").read_text())
    return layout_context(layouts, ref, index["manifests"][0]["digest"])


def layout_context(layouts: Path, ref: str, digest: str) -> str:
    """`oci-layout://<folder>:<tag>@<digest>`: the digest chooses the image; the tag (ref's, as
    the layout's index names it) is there for buildx 0.33.0, which turned a reference of a
    digest alone into `<store>:@<digest>` and failed ("invalid reference format",
    docker/buildx#3793); every other buildx takes the digest."""
    return f"oci-layout://{layout_folder(layouts, ref)}:{ref.rpartition(':')[2]}@{digest}"


def import_inputs(settings: Settings, repository: Path) -> List[str]:
    """What the image's upstream stage imports from: the repository's .repos files (relative
    paths), as the clone step finds them there, and with LOCKED docker-ros.lock (the commits
    it imports at). None when a before-dependency-identification hook exists: it runs first
    and may change them, so the source stage imports instead (the lock still comes along: the
    clone step of a locked build reads it, even when it imports nothing)."""
    found = [LOCK_FILE] if settings.locked and (repository / LOCK_FILE).is_file() else []
    if (repository / settings.before_dependency_identification_script).is_file():
        return found
    top = repository / settings.vcs_import_file
    if top.is_file():
        found.append(settings.vcs_import_file)
    if settings.enable_recursive_vcs_import:
        for directory in walk(repository):
            for entry in sorted(directory.glob("*.repos")):
                rel = entry.relative_to(repository).as_posix()
                if entry.is_file() and rel not in found:
                    found.append(rel)
    return found


def reads_whole_context(settings: Settings, repository: Path) -> bool:
    """Whether the image's source stage (clone, blacklist) must start from the whole build
    context: with a before-dependency-identification hook, which may change any file, or a
    .dockerignore, whose patterns skeleton_files (read here) would not apply."""
    return ((repository / settings.before_dependency_identification_script).is_file()
            or (repository / ".dockerignore").is_file())


def skeleton_files(settings: Settings, repository: Path) -> Optional[List[str]]:
    """The repository's files the source stage reads when no hook runs (the .repos files and
    what resolving reads, runtime.inputs), relative paths; None when it must read them all
    (reads_whole_context), or when a path setting is wrong: then the skeleton is empty and the
    source stage's own step reports the setting, as it would on the whole context."""
    if reads_whole_context(settings, repository):
        return None
    with tempfile.TemporaryDirectory(prefix="docker-ros-skeleton-") as tmp:
        ws = Workspace(tmp)
        ws.src.mkdir()
        ws.target.symlink_to(repository.resolve(), target_is_directory=True)
        try:
            found = resolve_inputs(ws, settings)
        except StepError:
            return None
        inputs = {p.relative_to(ws.target).as_posix() for p in found if ws.target in p.parents}
    return sorted(r for r in inputs | set(import_inputs(settings, repository)) if not left_out(r))


def additional_files_pattern(settings: Settings) -> Optional[str]:
    """ADDITIONAL_FILES_DIR as a line of the build's .dockerignore, when the build context can
    leave it out: the dev image's sources lose that folder (as docker-ros's), and without a
    whole-context source stage its files reach the image through the imports image
    (skeleton_files). Then no step removes it on each source edit, and its large files
    (models, maps) are not sent with the context. None when the source stage reads the whole
    context, when there is no such folder in the repository (or it is the repository), or
    when its path has characters a .dockerignore line would read as a pattern."""
    repository = Path(settings.build_context)
    if reads_whole_context(settings, repository) or not has_additional_files(settings):
        return None
    rel = os.path.normpath(settings.additional_files_dir)
    plain = rel == rel.strip() and not any(c in rel for c in "*?[]\\!#") and "\n" not in rel
    inside = not os.path.isabs(rel) and not rel.startswith("..")
    return "/" + rel if plain and inside else None


def has_additional_files(settings: Settings) -> bool:
    """Whether the repository has an ADDITIONAL_FILES_DIR folder (or link) other than itself,
    which the dev image's sources lose."""
    repository = Path(settings.build_context)
    folder = repository / settings.additional_files_dir
    return (folder.is_dir() or folder.is_symlink()) and folder.resolve() != repository.resolve()


def source_stages(settings: Settings) -> Dict[str, str]:
    """The build arguments choosing where the source stage starts and what the dev image's
    sources come from: the skeleton (only the files clone and blacklist read, so a source edit
    runs neither, nor resolve) and the checkout with the source stage's ignore markers, unless
    the source stage must read the whole context (reads_whole_context). The dev image's sources
    lose ADDITIONAL_FILES_DIR: left out of the build context (additional_files_pattern), else
    in a stage of their own (tree-pruned), which runs on every source edit."""
    repository = Path(settings.build_context)
    if reads_whole_context(settings, repository):
        return {"DOCKER_ROS_SOURCE_START": "checkout", "DOCKER_ROS_TREE": "source",
                "DOCKER_ROS_DEV_TREE": "tree-pruned"}
    step = has_additional_files(settings) and additional_files_pattern(settings) is None
    return {"DOCKER_ROS_SOURCE_START": "skeleton", "DOCKER_ROS_TREE": "marked",
            "DOCKER_ROS_DEV_TREE": "tree-pruned" if step else "tree-marked"}


def ensure_imports_image(settings: Settings, platform: str,
                         buildx: Sequence[str] = BUILDX, layouts: Optional[Path] = None) -> str:
    """A FROM-scratch image with the repository's .repos files at /repository and its
    skeleton_files at /inputs, tagged by their content. Each is COPY'd by the stage that
    needs it (content-addressed): the import stays cached while the .repos files do, and the
    source stage while the skeleton does. layouts: see scratch_image."""
    repository = Path(settings.build_context)
    with tempfile.TemporaryDirectory(prefix="docker-ros-imports-") as tmp:
        folders = imports_folders(settings, repository)
        for folder, files in folders.items():
            root = Path(tmp) / "context" / folder
            root.mkdir(parents=True)
            for rel in files:
                source, copy = repository / rel, root / rel
                copy.parent.mkdir(parents=True, exist_ok=True)
                copy.write_bytes(source.read_bytes())
                shutil.copymode(source, copy)  # hooks keep their executable bit
        # the repository is part of the tag too: it removes only images no other one uses
        mine = imports_owner(repository)
        ref = f"{IMPORTS_REPOSITORY}:{imports_digest(repository, folders)}-{mine[:8]}-{platform}"
        if layouts is None and image_exists(ref):
            return ref
        owner = {IMPORTS_LABEL: mine}
        scratch_image(Path(tmp), "context", ref, platform, into="/", buildx=buildx,
                      labels=owner, layouts=layouts)
    return ref


def imports_folders(settings: Settings, repository: Path) -> Dict[str, List[str]]:
    """The imports image's folders and the repository's files in each (relative paths)."""
    return {"repository": import_inputs(settings, repository),
            "inputs": skeleton_files(settings, repository) or []}


def imports_digest(repository: Path, folders: Mapping[str, Sequence[str]]) -> str:
    """The content digest of the imports image's files (16 hex digits): paths, modes (a hook's
    executable bit), contents; the layout is part of it (another version's image holds other
    folders)."""
    digest = hashlib.sha256()
    for folder, files in folders.items():
        digest.update(f"/{folder}/\0".encode())
        for rel in files:
            source = repository / rel
            mode = stat.S_IFREG | stat.S_IMODE(source.stat().st_mode)
            digest.update(f"{folder}/{rel}\0{mode:o}\0".encode() + source.read_bytes())
    return digest.hexdigest()[:16]


def imports_digest_of(ref: str) -> str:
    """The content digest in an imports image's tag (`<digest>-<owner>-<arch>`)."""
    return ref.rpartition(":")[2].split("-")[0]


def stale_dev_image(labels: Mapping[str, str], current: str, ref: str) -> str:
    """A warning when the dev image was built from other dependency inputs than the
    repository has now (a package.xml, a list file, the rosdep rules, a hook or a .repos file
    changed since), else "" (also for an image without the label: made by an older version)."""
    built = labels.get(INPUTS_LABEL, labels.get(OLD_LABELS[INPUTS_LABEL], ""))
    if not built or built == current:
        return ""
    return (f"docker-ros dev-shell: {ref} was built before the repository's dependency inputs "
            "changed (package.xml files, the list files, rosdep rules, hooks or .repos files): "
            "its dependencies may be out of date; `inv dev-shell --rebuild` builds it again "
            "first (from cache: only what changed)")


def remove_superseded_imports(settings: Settings, current: str) -> None:
    """The repository's other imports images of the platform go (see build_images: after a
    build, when no other build of the repository runs)."""
    owner = imports_owner(Path(settings.build_context))
    tags = [t for label in (IMPORTS_LABEL, OLD_LABELS[IMPORTS_LABEL])
            for t in engine.tags_labelled({label: owner})]
    engine.remove_quietly(superseded_imports(tags, current))


def imports_owner(repository: Path) -> str:
    """The label value of a repository's imports images (its absolute path, hashed)."""
    return hashlib.sha256(str(repository.resolve()).encode()).hexdigest()[:16]


def superseded_imports(tags: Iterable[str], current: str) -> List[str]:
    """The imports images of the same repository and platform as current, which replaces
    them (one per repository and platform stays; an edit back makes its image again, a few
    KB, and its steps stay cached by content)."""
    platform = current.rpartition("-")[2]
    return sorted(t for t in tags if t != current and t.startswith(f"{IMPORTS_REPOSITORY}:")
                  and t.rpartition("-")[2] == platform)


def ca_bundle(path: Path, destination: Path) -> Path:
    """EXTRA_CA_CERTS (one PEM file or a folder of them) as one file for a BuildKit secret."""
    if not path.exists():
        raise BuildError(f"EXTRA_CA_CERTS '{path}' not found: give a PEM file or a folder of them")
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    # (the PEM blocks are ASCII: a comment in another encoding stays out of the way)
    texts = [p.read_text(errors="ignore") for p in files]
    pems = [text for text in texts if "BEGIN CERTIFICATE" in text]
    if not pems:
        raise BuildError(f"EXTRA_CA_CERTS '{path}' holds no PEM certificate")
    destination.write_text("\n".join(pems))
    destination.chmod(0o600)
    return destination


def extra_ca_bundle(settings: Settings, folder: Path, name: str = "ca.pem") -> Optional[Path]:
    """EXTRA_CA_CERTS as one file `name` in folder (ca_bundle); None when it is not set."""
    if not settings.extra_ca_certs:
        return None
    return ca_bundle(Path(settings.extra_ca_certs).expanduser(), folder / name)
