"""The thin inference service: loads trained artifacts from the store and answers queries over REST and
gRPC. It evaluates models through each kind's `infer` (the registry) and holds no training code paths."""
