"""The `nbake` command line: the remote commands (jobs, downloads, queries and renders on the inference
service) here, commands that need the server's code added by the server package through the
`neuralbake.cli` entry point group (see `plugins`). Modules import the SDK and NumPy inside the commands
that use them, so `nbake` starts quickly.
"""
