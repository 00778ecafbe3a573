"""Markers of the generated-layer tests."""


def pytest_configure(config):
    config.addinivalue_line("markers", "install: builds and installs abyssal into a fresh venv (~10 s; offline)")
