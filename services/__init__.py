"""The job service, the inference service and the server's command line.

`workers` is imported first, before anything here loads torch: it sets OpenMP's passive wait."""

import workers  # noqa: F401
