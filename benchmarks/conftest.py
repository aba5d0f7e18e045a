"""Benchmarks are opt-in: ``--benchmark-enable`` times them; large sizes need ``-m slow``."""


def pytest_collection_modifyitems(config, items):
    if config.getoption("-m"):
        return
    for item in list(items):
        if item.get_closest_marker("slow"):
            items.remove(item)
