"""Generated protocol buffers of the neuralbake API (`make proto`); the package mirrors proto/neuralbake."""
