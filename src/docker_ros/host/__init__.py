"""Code that runs on the host: it talks to the Docker engine (the SDK and the CLI: builds,
images, containers, registries) and may use any installed library."""
