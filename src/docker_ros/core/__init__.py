"""What the host and the images share: the settings (declared, loaded, shown), CI detection
and the errors. Standard library only, Python >= 3.8: `build` copies it into every image with
in_image (the `tools` stage). It imports neither docker_ros.host nor the command line."""
