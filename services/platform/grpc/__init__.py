"""The gRPC server base both servers run beside their REST apps: token checks, error statuses, request
structs."""
