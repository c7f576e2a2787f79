"""The runner: deployed controllers, each in a sandboxed subprocess."""
