"""A scene carried between files, processes and nodes: read from and written to files (`io`), referenced
across a job's processes (`reference`), its files kept in the artifact store (`stored`) and in artifacts
(`portable`). The top layer of `workers.scene`."""
