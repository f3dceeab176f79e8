"""Figures (thesis Fig. 3.2/3.3 style) are built from any recording's signals."""

from __future__ import annotations

import numpy as np
import pytest

from cnctwin.exceptions import IdentificationError
from cnctwin.recording import Recording
from cnctwin.servo.figures import plot_error_signals, plot_tool_path

from ._refloop import RefLoop, run, standard_des


def test_tool_path_and_error_figures() -> None:
    des = standard_des()
    rx = run(RefLoop(), des, axis="X1")
    ry = run(RefLoop(kv_1_s=30.0), des[::-1].copy(), axis="Y1")
    rec = Recording(rx.hf.join(ry.hf.drop(columns="time")), meta=rx.meta)
    fig = plot_tool_path(rec, ("X1", "Y1"), magnify=20)
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert any("CTRL_POS" in lab and "x20" in lab for lab in labels)
    assert any("ENC_POS" in lab for lab in labels)
    fig2 = plot_error_signals(rec, "X1")
    labels2 = [t.get_text() for t in fig2.axes[0].get_legend().get_texts()]
    assert any("following error" in lab for lab in labels2)
    assert any("CTRL_DIFF2" in lab for lab in labels2)


def test_figures_refuse_missing_signals() -> None:
    rec = Recording.from_arrays(np.arange(5), {"CURRENT|X1": np.zeros(5)})
    with pytest.raises(IdentificationError):
        plot_tool_path(rec)
    with pytest.raises(IdentificationError):
        plot_error_signals(rec, "X1")
