"""What COMMAND will start, checked where it will run (the run image's build, after the install
space is in): the programs it names, and for `ros2 run|launch`, `rosrun` and `roslaunch` the
package, executable or launch file, found the way those tools find them. Conservative: what
the shell decides only at run time (expansions, compound commands, anything after `source` or
`cd`) is not checked, and a program named by its path may come from a volume.
Standard library only, Python 3.8+ (runs inside images)."""

import difflib
import os
import shlex
from pathlib import Path
from typing import Iterator, List, Mapping, Optional, Sequence, Tuple

# words that make the rest of the command line depend on the shell at run time
COMPOUND = {"if", "then", "else", "elif", "fi", "for", "while", "until", "do", "done", "case",
            "esac", "function", "select", "{", "}", "[[", "]]", "!", "(", ")", "time", "coproc"}
# builtins after which the environment (and so what a later word names) may differ
ENV_CHANGING = {"source", ".", "export", "cd", "pushd", "popd", "eval", "set", "unset", "alias",
                "declare", "typeset", "local", "readonly", "shopt", "enable", "hash", "trap"}
CONTROL = {";", "&&", "||", "|", "&", ";;", "|&"}
REDIRECT = set("<>&")
UNKNOWABLE = set("$`*?[~{")

# each launcher's options that take a value (the others are switches)
VALUED = {
    "ros2 run": {"--prefix"},
    "ros2 launch": {"--launch-prefix", "--launch-prefix-filter"},
    "rosrun": {"--prefix"},
    "roslaunch": {"-p", "--port", "--args", "--find-node", "-c", "--child", "-u",
                  "--server_uri", "--run_id", "--pid", "-w", "--numworkers", "-t", "--timeout",
                  "--master-logger-level", "--sigint-timeout", "--sigterm-timeout"},
}
SWITCHES = {
    "ros2 run": {"--debug"},
    "ros2 launch": {"-n", "--noninteractive", "-d", "--debug", "-p", "--print",
                    "--print-description", "-s", "--show-args", "--show-arguments", "-a",
                    "--show-all-subprocesses-output"},
    "rosrun": {"--debug"},
    "roslaunch": {"--files", "--nodes", "--local", "--screen", "--wait", "--core", "-v",
                  "--dump-params", "--skip-log-check", "--ros-args", "--disable-title",
                  "--required", "--log"},
}


def simple_commands(command: str) -> List[List[str]]:
    """The words of COMMAND's simple commands that are sure to run in the environment the image
    gives (leading assignments, `exec` and redirections removed), up to the first that may change
    it or that the shell shapes at run time; [] when the line does not parse."""
    lexer = shlex.shlex(command.replace("\n", ";"), posix=True, punctuation_chars=True)
    lexer.whitespace_split = True
    try:
        tokens = list(lexer)
    except ValueError:
        return []
    out: List[List[str]] = []
    for words in _segments(tokens):
        while words and _assignment(words[0]):
            if words[0].startswith("PATH="):
                return out
            words = words[1:]
        if words and words[0] == "exec":
            words = words[1:]
        if not words:
            return out  # assignments alone change the environment
        first = words[0]
        if first in COMPOUND or first in ENV_CHANGING or set(first) & UNKNOWABLE:
            return out
        out.append(words)
    return out


def _segments(tokens: Sequence[str]) -> Iterator[List[str]]:
    words: List[str] = []
    skip = False
    for token in tokens:
        if token in CONTROL:
            yield words
            words = []
        elif token and set(token) <= REDIRECT:
            skip = True  # the redirection's target follows
        elif skip:
            skip = False
        else:
            words.append(token)
    yield words


def _assignment(word: str) -> bool:
    name, sep, _ = word.partition("=")
    return bool(sep) and name.isidentifier()


def launcher(words: Sequence[str]) -> Optional[Tuple[str, List[str]]]:
    """(launcher, its positional words) for `ros2 run|launch`, `rosrun`, `roslaunch`; None for
    any other command, or when an option is one we do not know (so we cannot tell the words
    apart) or a word is only known at run time."""
    if words[:2] in (["ros2", "run"], ["ros2", "launch"]):
        name, rest = " ".join(words[:2]), list(words[2:])
    elif words[0] in ("rosrun", "roslaunch"):
        name, rest = words[0], list(words[1:])
    else:
        return None
    positional: List[str] = []
    while rest and len(positional) < 2:
        word = rest.pop(0)
        option = word.split("=", 1)[0]
        if word.startswith("-") and option in VALUED[name]:
            if "=" not in word and rest:
                rest.pop(0)
        elif word.startswith("-") and option in SWITCHES[name]:
            continue
        elif word.startswith("-"):
            return None
        elif ":=" in word:
            break  # launch arguments start
        else:
            positional.append(word)
    if any(set(word) & UNKNOWABLE for word in positional):
        return None
    return name, positional


def package_dirs(package: str, env: Mapping[str, str], ros2: bool) -> Optional[Tuple[Path, Path]]:
    """(share, lib) folders of an installed package: ROS 2 through the ament index (as `ros2 pkg
    prefix`); ROS 1 as <prefix>/share/<package> of CMAKE_PREFIX_PATH (catkin install spaces,
    Debian's /usr) or ROS_PACKAGE_PATH, or a source folder <package> there (share and lib)."""
    if ros2:
        for prefix in _paths(env, "AMENT_PREFIX_PATH"):
            if (prefix / "share/ament_index/resource_index/packages" / package).is_file():
                return prefix / "share" / package, prefix / "lib" / package
        return None
    for prefix in [*_paths(env, "CMAKE_PREFIX_PATH"), Path("/usr")]:
        if (prefix / "share" / package / "package.xml").is_file():
            return prefix / "share" / package, prefix / "lib" / package
    for root in _paths(env, "ROS_PACKAGE_PATH"):
        for folder in (root / package, root):
            if folder.name == package and (folder / "package.xml").is_file():
                if folder.parent.name == "share":
                    return folder, folder.parent.parent / "lib" / package
                return folder, folder
    return None


def package_names(env: Mapping[str, str], ros2: bool) -> List[str]:
    """The names of the packages package_dirs finds here (for a name close to a typo's)."""
    if ros2:
        return sorted({index.name for prefix in _paths(env, "AMENT_PREFIX_PATH") for index in
                       (prefix / "share/ament_index/resource_index/packages").glob("*")})
    manifests = [manifest for prefix in [*_paths(env, "CMAKE_PREFIX_PATH"), Path("/usr")]
                 for manifest in (prefix / "share").glob("*/package.xml")]
    for root in _paths(env, "ROS_PACKAGE_PATH"):
        manifests += [root / "package.xml", *root.glob("*/package.xml")]
    return sorted({manifest.parent.name for manifest in manifests if manifest.is_file()})


def did_you_mean(name: str, names: Sequence[str]) -> str:
    """`; did you mean <the closest of names>?`, or "" when none is close."""
    close = difflib.get_close_matches(name, names, n=1)
    return f"; did you mean {close[0]}?" if close else ""


def _paths(env: Mapping[str, str], name: str) -> List[Path]:
    return [Path(p) for p in env.get(name, "").split(os.pathsep) if p]


def usable(path: Path, *, executable: bool) -> bool:
    """Whether path is a file (an executable one if asked)."""
    return path.is_file() and (not executable or os.access(path, os.X_OK))


def files_below(folders: Sequence[Path], *, executable: bool) -> Iterator[Path]:
    """The files below folders (executable ones if asked), hidden folders left out."""
    for folder in folders:
        for dirpath, dirnames, filenames in os.walk(folder, followlinks=True):
            dirnames[:] = [d for d in dirnames if not d.startswith(".")]
            yield from (path for path in (Path(dirpath, name) for name in filenames)
                        if usable(path, executable=executable))


def find_file(folders: Sequence[Path], name: str, *, executable: bool) -> bool:
    """Whether a file called name is anywhere below folders (an executable one if asked), as
    `ros2 run` looks in lib/<package> and `ros2 launch`/`roslaunch`/`rosrun` in its share; a
    name with a folder in it (`launch/x.launch.py`) is looked for there only."""
    if "/" in name:
        return any(usable(folder / name, executable=executable) for folder in folders)
    return any(path.name == name for path in files_below(folders, executable=executable))


def file_names(folders: Sequence[Path], *, executable: bool) -> List[str]:
    """The names of the files below folders (executable ones if asked)."""
    return sorted({path.name for path in files_below(folders, executable=executable)})


def launcher_problem(name: str, positional: Sequence[str], env: Mapping[str, str]) -> str:
    """What keeps `name positional...` from finding its package, executable or launch file
    here, or "". A launch file given by its path (one positional, or a path) is not checked."""
    if len(positional) < 2 or "/" in positional[0] or positional[0].endswith(
            (".launch", ".xml", ".py", ".yaml")):
        return ""
    package, item = positional
    ros2 = name.startswith("ros2")
    found_dirs = package_dirs(package, env, ros2=ros2)
    if found_dirs is None:
        return (f"package {package} is not in the run image: neither built in the workspace "
                f"nor installed{did_you_mean(package, package_names(env, ros2))} (check the "
                "name; a package of another repository needs an <exec_depend> on it in a "
                "package.xml, or an entry in the .repos file)")
    share, lib = found_dirs
    # (a ROS 1 source folder is both share and lib: looked in once)
    where = list(dict.fromkeys({"ros2 run": [lib], "rosrun": [lib, share]}.get(name,
                                                                            [share, lib])))
    runs = name.endswith("run")
    if find_file(where, item, executable=runs):
        return ""
    kind = "executable" if runs else "launch file"
    close = did_you_mean(item.rsplit("/", 1)[-1], file_names(where, executable=runs))
    return (f"package {package} has no {kind} {item}{close} (looked in "
            f"{', '.join(str(w) for w in where)}; check the name, and that the package "
            "installs it)")


def package_executables(name: str, env: Mapping[str, str]) -> List[Tuple[str, Path, bool]]:
    """(package, path, ROS 2) of each executable file called name in lib/<package>/ of the
    install prefixes (AMENT_PREFIX_PATH: ROS 2; CMAKE_PREFIX_PATH: ROS 1), where colcon puts
    an ament_python package's console scripts and `ros2 run`/`rosrun` find them."""
    found: List[Tuple[str, Path, bool]] = []
    for variable, ros2 in (("AMENT_PREFIX_PATH", True), ("CMAKE_PREFIX_PATH", False)):
        for prefix in _paths(env, variable):
            for path in sorted(prefix.glob(f"lib/*/{name}")):
                if path.is_file() and os.access(path, os.X_OK) and \
                        path not in [p for _, p, _ in found]:
                    found.append((path.parent.name, path, ros2))
    return found


def not_on_path(first: str, env: Mapping[str, str], found: Sequence[str]) -> str:
    """Why COMMAND's program `first` cannot start, and what would start what was meant: a
    package's executable by `ros2 run`/`rosrun` or its path; a missing `ros2` from a package."""
    problem = f"`{first}` is not a program on PATH in the run image"
    executables = package_executables(first, env)
    if executables:
        package, path, ros2 = executables[0]
        tool = "ros2 run" if ros2 else "rosrun"
        ways = ([f"`{tool} {package} {first}`"] if tool.split()[0] in found else []) + [
            f"its path {path}"]
        return f"{problem}: it is an executable of package {package}; start it with " + \
            " or ".join(ways)
    if first == "ros2":
        return (f"{problem}: the ROS 2 command line (ros2cli) is not installed; an "
                "<exec_depend> on ros2run or ros2launch in a package.xml installs it where "
                "rosdep knows them (Debian's ROS 2 packages have none: start a node by its "
                "path, /docker-ros/ws/install/<package>/lib/<package>/<executable>)")
    return f"{problem} (check the name; a program that comes with a volume at run time: give " \
        "its path)"


def command_problems(command: str, env: Mapping[str, str], found: Sequence[str]) -> List[str]:
    """What COMMAND names that this environment lacks: programs not on PATH (found: the first
    words `type -t` knows here) and launchers' packages, executables and launch files."""
    problems: List[str] = []
    for words in simple_commands(command):
        first = words[0]
        if "/" not in first and first not in found:
            problems.append(not_on_path(first, env, found))
            continue
        parsed = launcher(words)
        if parsed:
            problem = launcher_problem(*parsed, env)
            if problem:
                problems.append(f"`{' '.join(words)}`: {problem}")
    return problems
