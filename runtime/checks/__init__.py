"""`abyssal verify` and `abyssal bench`: sections imported explicitly, reference models, peers."""
