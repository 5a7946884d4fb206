"""Sample CSVs read two ways (``station.formats.samples``): a file of numbers only whole by numpy's
parser, any other cell by cell; both give the same sample set, and a file numpy reads but whose
cell fails a check is read again so that the error names the cell."""

import dataclasses

import numpy as np
import pytest

from errors import InputError
from sim_fixtures.scenario import write_scenario
from station.formats import samples as fmt


def by_cells(path):
    header, body = fmt.read_csv(path, "samples")
    return fmt._samples(path, header, fmt._Cells(path, body))


def test_a_plain_file_is_read_whole_and_as_the_cells_read_it(tmp_path):
    path = write_scenario(tmp_path, seed=2, n_lines=3, n_per_line=10).samples
    assert fmt._plain_table(path) is not None
    whole, cells = fmt.load_samples(path), by_cells(path)
    for field in dataclasses.fields(fmt.Samples):
        a, b = getattr(whole, field.name), getattr(cells, field.name)
        assert np.array_equal(a, b, equal_nan=True) if isinstance(a, np.ndarray) else a == b, field.name


@pytest.mark.parametrize(
    ("column", "cell", "said"),
    [
        ("q2_deg", "1e6", "row 3 (line 5): q2_deg: '1e6' is outside -"),
        ("line", "1.5", "row 3 (line 5): line: '1.5' is not a line id"),
        ("length_mm", "inf", "row 3 (line 5): length_mm: 'inf' is not a finite number"),
    ],
)
def test_a_number_that_fails_its_check_is_named_by_its_cell(tmp_path, column, cell, said):
    path = write_scenario(tmp_path, seed=2, n_lines=3, n_per_line=10).samples
    lines = path.read_text().splitlines()
    at = lines[0].split(",").index(column)
    cells = lines[4].split(",")
    cells[at] = cell
    lines[4] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    assert fmt._plain_table(path) is not None  # numpy reads it: the checks send it back
    with pytest.raises(InputError, match=said.replace("(", r"\(").replace(")", r"\)")):
        fmt.load_samples(path)
