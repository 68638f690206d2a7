"""Content-addressed storage for artifacts and uploaded scenes (docs/job-service-contracts.md, section 3).

`store` holds blobs by sha256; `manifest` and `assets` are the records that name them;
`artifacts` publishes job outputs and keeps checkpoints; `uploads` turns a multipart upload
into a validated asset (with `staging`, `archives` and `validation`).
"""
