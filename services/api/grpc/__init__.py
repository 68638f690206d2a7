"""The gRPC adapter over the job service: the same `Services` objects the REST app uses, reached through
the `neuralbake.v1` protocol (stubs generated into the `neuralbake-client` package by `make proto`).
"""
