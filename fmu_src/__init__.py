"""Sources that go into the exported FMUs (the pythonfmu slave and the native C framework)."""
