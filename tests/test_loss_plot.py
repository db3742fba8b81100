"""loss.png of a training run: each term raw and as a trailing running mean."""

import math

import numpy as np
import pytest

from mitsvbrdf.training.loss_plot import running_mean, smoothing_window, write_loss_plot


def test_running_mean_of_a_constant_series_is_that_constant():
    assert np.array_equal(running_mean([0.25] * 7, 3), np.full(7, 0.25))


def test_running_mean_averages_the_last_window_entries():
    assert running_mean([1.0, 2.0, 3.0, 4.0], 2).tolist() == [1.0, 1.5, 2.5, 3.5]


def test_running_mean_leaves_out_steps_where_a_term_was_not_logged():
    assert running_mean([1.0, math.nan, 3.0, math.nan], 2).tolist() == [1.0, 1.0, 3.0, 3.0]
    assert math.isnan(running_mean([math.nan, math.nan], 2)[1])


def test_running_mean_rejects_a_window_below_one():
    with pytest.raises(ValueError, match="window"):
        running_mean([1.0], 0)


def test_smoothing_window_is_two_percent_of_the_logged_steps_and_at_least_one():
    assert (smoothing_window(10), smoothing_window(500), smoothing_window(20413)) == (1, 10, 408)


def test_loss_plot_is_drawn_from_metrics_csv_rows_with_terms_missing_at_some_steps(tmp_path):
    from PIL import Image

    rows = [{"step": str(s), "loss": str(1.0 / s), "inverse": "" if s % 2 else "0.3", "lr": "1e-3"}
            for s in range(1, 40)]
    write_loss_plot(rows, tmp_path / "loss.png", "stage2: runs/x")
    with Image.open(tmp_path / "loss.png") as im:
        assert im.size == (600, 350)  # 6 x 3.5 inches at 100 dpi
