"""Code that runs inside the images (and may run on the host too): the steps, what they run
on, the test and slim-trace runners. Standard library only, Python >= 3.8: `build` copies
this package and docker_ros.core (the settings, CI detection) into every image (the `tools`
stage). It never imports from docker_ros.host or the command line (a unit test checks it)."""
