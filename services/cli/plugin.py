"""What the server package adds to the `nbake` of neuralbake-client (entry point group `neuralbake.cli`):
the commands that need the server's code (torch, Ray, the path tracer), each imported only when it runs.
The summaries are the commands' first docstring lines (a test keeps them equal).
"""

from __future__ import annotations

from neuralbake_client.cli.plugins import CommandRef, Plugin

PLUGIN = Plugin(
    commands=(
        CommandRef(
            "serve",
            "services.cli.serve:serve_command",
            "Serve the REST API (OpenAPI at /docs) and run submitted jobs on Ray.",
        ),
        CommandRef(
            "serve-inference",
            "services.cli.serve_inference:serve_inference_command",
            "Serve trained artifacts for queries and renders, over REST and gRPC.",
        ),
    ),
    scene_render=CommandRef(
        "render",
        "services.cli.render:render_command",
        "Path-trace SCENE to a linear HDR OpenEXR (float32) and an sRGB PNG preview.",
    ),
)
