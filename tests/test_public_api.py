import pytest

import easyhoi


def test_every_public_name_resolves():
    for name in easyhoi.__all__:
        assert getattr(easyhoi, name) is not None, name
    assert easyhoi.get_preset("paper").name == "paper"


def test_unknown_attribute_raises_attribute_error():
    with pytest.raises(AttributeError):
        easyhoi.does_not_exist  # noqa: B018
