"""hal.drives re-exports hal.drives_base's public names from its one list (no second list)."""

import hal.drives as drives
import hal.drives_base as base


def test_every_base_name_is_exported_once_and_is_the_same_object():
    assert len(drives.__all__) == len(set(drives.__all__))
    assert set(base.__all__) <= set(drives.__all__)
    for name in base.__all__:
        assert getattr(drives, name) is getattr(base, name)


def test_its_own_names_are_exported_and_defined():
    assert {"WinchDrives", "DriveState", "DriveConfigError"} <= set(drives.__all__)
    assert all(hasattr(drives, n) for n in drives.__all__)
    ns: dict = {}
    exec("from hal.drives import *", ns)
    assert set(drives.__all__) <= set(ns)
