"""How DfFModel.infer tiles a frame (aat_deploy.infer.model.tile_grid): counted by hand for the RF50's 960 x 640."""

import numpy as np
import pytest

from aat_deploy.infer.model import tile_grid


def test_the_rf50_frame_in_the_any_camera_nets_128_px_tiles_counted_by_hand():
    # step 96: rows 0, 96, ..., 480 and the last at 640 - 128 = 512; columns 0, ..., 768 and 960 - 128 = 832
    tile, overlap, ys, xs = tile_grid(640, 960, 128, 32, 32)
    assert (tile, overlap) == (128, 32)
    assert ys == [0, 96, 192, 288, 384, 480, 512] and xs == [0, 96, 192, 288, 384, 480, 576, 672, 768, 832]
    _, _, ys, xs = tile_grid(640, 960, 128, 0, 32)  # no overlap: only the last row and column overlap
    assert ys == [0, 128, 256, 384, 512] and xs == [0, 128, 256, 384, 512, 640, 768, 832]


@pytest.mark.parametrize("h,w,tile,overlap,multiple", [(640, 960, 128, 16, 32), (100, 333, 50, 40, 32),
                                                      (96, 64, 128, 8, 32), (480, 640, 96, 24, 1)])
def test_tiles_cover_the_frame_inside_it_with_the_overlap_capped_at_a_quarter(h, w, tile, overlap, multiple):
    t, o, ys, xs = tile_grid(h, w, tile, overlap, multiple)
    assert t % multiple == 0 and t >= tile and o == min(overlap, t // 4)
    cover = np.zeros((h, w), bool)
    for y in ys:
        for x in xs:
            assert y >= 0 and x >= 0 and (y + t <= h or y == 0) and (x + t <= w or x == 0)
            cover[y:y + t, x:x + t] = True
    assert cover.all()
