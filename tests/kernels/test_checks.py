"""``kernels.checks.check_shape``: symbolic shapes bound across arguments, and messages
that name the argument, the expected shape and the shape given."""

from __future__ import annotations

import pytest
import torch

from kernels.checks import FLOATING_DTYPES, ShapeDims, check_above_plane, check_shape


def test_binds_symbolic_dims_and_checks_them_across_arguments():
    dims = ShapeDims()
    assert check_shape(torch.zeros(2, 3, 8, 6), "B 3 H W", name="photo", dims=dims) is dims
    assert dict(dims) == {"B": 2, "H": 8, "W": 6}
    check_shape(torch.zeros(2, 5, 3), "B K 3", name="light_pos", dims=dims)
    assert dims["K"] == 5
    with pytest.raises(
        ValueError, match=r"^mask must have shape \[B, 1, H, W\], got \(2, 1, 8, 7\): W is 7, but 6 in photo$"
    ):
        check_shape(torch.zeros(2, 1, 8, 7), "B 1 H W", name="mask", dims=dims)


def test_a_plain_dict_works_without_sources():
    dims = {"H": 4}
    with pytest.raises(ValueError, match=r"H is 5, but 4 bound earlier"):
        check_shape(torch.zeros(3, 5, 5), "3 H W", name="photo", dims=dims)


@pytest.mark.parametrize(
    "shape, pattern, why",
    [
        ((2, 3, 4), "B 3 H W", r"3 dims, expected 4"),
        ((2, 4, 4, 4), "B 3 H W", r"dim 1 is 4, expected 3"),
        ((2, 4), "* 3 H W", r"2 dims, expected at least 3"),
    ],
)
def test_messages_give_the_expected_and_given_shapes(shape, pattern, why):
    with pytest.raises(ValueError) as err:
        check_shape(torch.zeros(shape), pattern, name="x")
    expected = "[" + ", ".join(pattern.split()) + "]"
    assert str(err.value).startswith(f"x must have shape {expected}, got {shape}: ")
    assert err.match(why)


def test_variadic_dims_bind_as_tuples():
    dims = check_shape(torch.zeros(4, 2, 3, 5, 5), "*batch 3 H W", name="a")
    assert dims["batch"] == (4, 2)
    check_shape(torch.zeros(4, 2, 1, 5, 5), "*batch 1 H W", name="b", dims=dims)
    with pytest.raises(ValueError, match=r"batch is \(4,\), but \(4, 2\) in a"):
        check_shape(torch.zeros(4, 1, 5, 5), "*batch 1 H W", name="c", dims=dims)
    check_shape(torch.zeros(3, 5, 5), "* 3 H W", name="unbatched", dims=dims)  # plain * binds nothing


def test_alternatives_accept_any_and_bind_the_first_that_matches():
    for shape in [(3,), (7, 3), (2, 7, 3)]:
        check_shape(torch.zeros(shape), ("3", "K 3", "B K 3"), name="pos")
    dims = check_shape(torch.zeros(2, 7, 3), ("3", "K 3", "B K 3"), name="pos")
    assert dict(dims) == {"B": 2, "K": 7}
    with pytest.raises(ValueError, match=r"pos must have shape \[3\], \[K, 3\] or \[B, K, 3\], got \(7, 4\): dim 1"):
        check_shape(torch.zeros(7, 4), ("3", "K 3", "B K 3"), name="pos")
    with pytest.raises(ValueError, match=r"got \(1, 2, 3, 3\): 4 dims$"):
        check_shape(torch.zeros(1, 2, 3, 3), ("3", "K 3", "B K 3"), name="pos")


def test_type_errors_for_non_tensors_and_dtypes():
    with pytest.raises(TypeError, match=r"photo must be a torch.Tensor, got list"):
        check_shape([1.0, 2.0], "N", name="photo")
    with pytest.raises(TypeError, match=r"photo must be float32 or float64, got torch.float16"):
        check_shape(torch.zeros(3, dtype=torch.float16), "N", name="photo")
    with pytest.raises(TypeError, match=r"images must be a floating-point tensor, got torch.int64"):
        check_shape(torch.zeros(3, dtype=torch.int64), "N", name="images", dtypes=FLOATING_DTYPES)
    check_shape(torch.zeros(3, dtype=torch.bfloat16), "N", name="images", dtypes=FLOATING_DTYPES)
    check_shape(torch.zeros(3, dtype=torch.uint8), "N", name="any", dtypes=None)


def test_finite_and_above_plane():
    t = torch.zeros(2, 3)
    t[1, 0] = float("inf")
    check_shape(t, "N 3", name="pos")
    with pytest.raises(ValueError, match=r"pos holds 1 NaN or inf value"):
        check_shape(t, "N 3", name="pos", finite=True)
    with pytest.raises(ValueError, match=r"camera_pos has a position on or below the material plane"):
        check_above_plane("camera_pos", torch.tensor([[0.0, 0.0, 4.0], [1.0, 1.0, 0.0]]))


def test_a_bad_pattern_is_the_callers_error():
    with pytest.raises(ValueError, match="bad token"):
        check_shape(torch.zeros(3), "B-1", name="x")
    with pytest.raises(ValueError, match="more than one variadic"):
        check_shape(torch.zeros(3), "* 3 *", name="x")
