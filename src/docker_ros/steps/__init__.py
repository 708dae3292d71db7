"""The ten pipeline steps. Standard library only, Python 3.8+: this package also runs inside images."""

STEPS = ("clone", "blacklist", "scripts", "rosdep", "debs", "pip", "files", "custom", "colcon", "command")
