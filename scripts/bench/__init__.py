"""Benchmark docker-ros image builds (issue 5, "Fast rebuilds"): figures, never assertions.

Generates a workspace of N C++ packages (cmake build type, chains of dependent shared
libraries, one rosdep key), then in ONE run and strictly one after the other builds it with the
real CLI (`python -m docker_ros build`, TARGET=dev,run from the workspace's .env) and times:

  1   cold build (bench images removed; the workspace is new to the engine: a run id in its
      additional files and new cache mount ids. Nothing is pruned: the engine is shared, so
      the base image's prepared layer and the apt download cache may be warm)
  2   no-change rebuild
  3   one-file change in the LAST package (nothing depends on it)
  B   baseline: what the original docker-ros does after that change, a full `colcon build` of
      the workspace from scratch, in a fresh container of the dev image
  3b  one-file change in the FIRST package (others depend on it)
  F   BuildKit floor: a cached bake of two trivial targets (what building two images costs
      here whatever they hold; scenario 3 is also set against L plus F)
  4   one added apt dependency (a <depend> on another rosdep key)
  5   dev and run image sizes
  6   imports: a second workspace whose N packages come through .repos from a local git
      server (git daemon on the loopback, BUILD_NETWORK=host) plus one package of its own:
      cold build, then one .cpp changed in its own package (to set against 3: the same edit
      with every package in the repository), then the .repos file touched (re-import)
  7   lean run image (ENABLE_LEAN_RUN_IMAGE, run target, tag `lean`) after scenario 4: its
      size over the base against the default run image's, every node run in it; then 7b, one
      .cpp changed in the last package, rebuilt lean (against the physical limit too)
  8   slim image (ENABLE_SLIM) of the run image after 7b, then 8b, the same build again: the
      slim image is up to date (its figure; tests/docker/test_slim.py checks it, untimed)
  9   CI jobs on empty runners through a local registry, with CI's build state
      (BUILD_STATE_FROM) and CACHE_FROM: job 1 builds and pushes; 9b one .cpp changed in the
      last package, 9c nothing changed, each in a checkout of its own (an empty colcon build/
      cache; BuildKit's layer cache of the shared engine is not emptied)

and checks while measuring that the run image runs the changed code. Prints one table;
--json writes the figures to a file. Timings are wall-clock and as noisy as the machine.
"""

import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
# run from a checkout: the tool's package without installing it, and the tests' helpers
for folder in (REPO / "src", REPO):
    if str(folder) not in sys.path:
        sys.path.insert(0, str(folder))


class BenchError(Exception):
    """A measurement that could not be made (the bench stops, keeping its workspace and log)."""
