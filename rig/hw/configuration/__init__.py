"""Configuration sources a rig config can choose (`configuration.source:`), and the factory for them."""
