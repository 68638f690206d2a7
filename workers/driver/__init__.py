"""The job driver: runs a job's kind inside a Ray actor and answers the service. It sits above the
registry of kinds (it looks a job's kind up by name) and below the services that start it."""
