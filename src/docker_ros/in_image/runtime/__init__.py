"""What the steps run on, in images and on the host. Standard library only, Python 3.8+."""
