"""What the tests share: paths, reference implementations (oracles), fake devices and clients."""
