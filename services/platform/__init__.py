"""What both servers (the job API in `services.api`, the inference service in `services.inference`) stand
on: the error base and its problem table, problem+json, security headers, body limits, readiness, ports,
bearer-token auth, the gRPC server base and the settings base. It imports neither server."""
