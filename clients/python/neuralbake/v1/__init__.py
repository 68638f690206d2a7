"""Stubs generated from proto/neuralbake/v1 by `make proto`; never edit them by hand."""
