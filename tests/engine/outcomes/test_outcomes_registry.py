"""The cut-point registry: every row's thresholds against the published table as quoted here,
with where each number was read; keys, metrics and bands.

The numbers below are quoted from GGIR's cut-point table (wadpac/GGIR vignettes/CutPoints.Rmd at
commit 388064b707df4fcfb7f9b755c5a43a477d371092, the lines named per row), which gives each
publication's DOI. The publications' own tables (Hildebrand 2014 doi:10.1249/MSS.0000000000000289;
Hildebrand 2017 doi:10.1111/sms.12795; Mielke 2023 doi:10.1111/sms.14416; Vähä-Ypyä 2015
doi:10.1371/journal.pone.0134813) are the authority; a row's ``table``/``page`` fields are
empty until a row has been checked against them.
"""

import pytest

from stillpoint.engine.outcomes.cutpoints import lookup, registry

# key: (light, moderate, vigorous) in mg, source lines in CutPoints.Rmd
QUOTED = {
    "hildebrand_children_actigraph_wrist": ((35.6, 201.4, 707.0), "151-153"),
    "hildebrand_children_geneactiv_wrist": ((56.3, 191.6, 695.8), "155-157"),
    "hildebrand_children_actigraph_hip": ((63.3, 142.6, 464.6), "159-161"),
    "hildebrand_children_geneactiv_hip": ((64.1, 152.8, 514.3), "163-165"),
    "hildebrand_adults_actigraph_wrist": ((44.8, 100.6, 428.8), "199-201"),
    "hildebrand_adults_geneactiv_wrist": ((45.8, 93.2, 418.3), "203-205"),
    "hildebrand_adults_actigraph_hip": ((47.4, 69.1, 258.7), "207-209"),
    "hildebrand_adults_geneactiv_hip": ((46.9, 68.7, 266.8), "211-213"),
    "mielke2023_geneactiv_nondominant_wrist": ((36, 92, 283), "215-217"),
    "mielke2023_actigraph_nondominant_wrist": ((25, 78, 249), "219-221"),
    "mielke2023_geneactiv_dominant_wrist": ((30, 85, 270), "223-225"),
    "mielke2023_actigraph_hip": ((40, 65, 190), "227-229"),  # "ActiGraph – waist" (GGIR #1417)
    "vahaypya2015_mad_hip": ((None, 91, 414), "231-233"),  # "Light: N/A"
}


@pytest.mark.parametrize("key", sorted(QUOTED))
def test_row_matches_the_quoted_table(key):
    (light, moderate, vigorous), lines = QUOTED[key]
    row = lookup(key)
    assert (row.light, row.moderate, row.vigorous) == (light, moderate, vigorous)
    assert f"CutPoints.Rmd@388064b7 lines {lines}" in row.transcribed_from
    assert row.doi and row.year and row.population and row.device and row.placement


def test_mielke_rows_agree_with_the_article_as_quoted_in_ggir_issue_1417():
    # wadpac/GGIR issue 1417 quotes Mielke et al. 2023's table: GENEActiv non-dominant wrist
    # 36/92/283, ActiGraph non-dominant wrist 25/78/249, GENEActiv dominant wrist 30/85/270,
    # ActiGraph waist 40/65/190 (light >= 1.5 MET, moderate >= 3 MET, vigorous >= 6 MET)
    assert lookup("mielke2023_actigraph_hip").placement == "waist"
    assert "issue 1417" in lookup("mielke2023_actigraph_hip").transcribed_from


def test_mad_row_agrees_with_the_article():
    # Vähä-Ypyä et al. 2015, PLoS One 10(8): e0134813, abstract, Results: "The optimal cut-point
    # was 91 mg (milligravity) for 3 MET and 414 mg for 6 MET" (light/moderate and
    # moderate/vigorous; the article sets no light threshold)
    row = lookup("vahaypya2015_mad_hip")
    assert (row.light, row.moderate, row.vigorous) == (None, 91, 414)
    assert (row.table, row.page) == ("abstract (Results)", "e0134813")


# ActiLife-count rows: (light, moderate, vigorous) per the publication's epoch (s), as quoted in
# each row's ``transcribed_from`` (Troiano's from Am J Epidemiol 2016 Table 2)
QUOTED_COUNTS = {
    "freedson1998_adults_axis1": ((100, 1952, 5725), 60, "axis1"),
    "troiano2008_nhanes_adults_axis1": ((100, 2020, 5999), 60, "axis1"),
    "evenson2008_children_axis1": ((26, 574, 1003), 15, "axis1"),
    "sasaki2011_adults_vm": ((None, 2690, 6167), 60, "vm"),
}


# the articles' own abstracts (Results), which give the thresholds: Freedson et al. 1998, MSSE
# 30(5):777, "count ranges corresponding to light, moderate, hard, and very hard intensity levels
# were <= 1951, 1952-5724, 5725-9498, >= 9499 cnts.min-1"; Sasaki et al. 2011, J Sci Med Sport
# 14(5):411, "VM3 cut-points for moderate, hard, and very hard PA intensities were 2690-6166,
# 6167-9642, >9642 counts.min-1" (moderate and hard are the rows' moderate and vigorous)
ARTICLE_ABSTRACTS = {
    "freedson1998_adults_axis1": ((1952, 5724), (5725, 9498), "777"),
    "sasaki2011_adults_vm": ((2690, 6166), (6167, 9642), "411"),
}


@pytest.mark.parametrize("key", sorted(ARTICLE_ABSTRACTS))
def test_count_rows_agree_with_the_articles_abstracts(key):
    moderate, hard, page = ARTICLE_ABSTRACTS[key]
    row = lookup(key)
    assert (row.moderate, row.vigorous) == (moderate[0], hard[0])
    assert (row.table, row.page) == ("abstract (Results)", page)


@pytest.mark.parametrize("key", sorted(QUOTED_COUNTS))
def test_count_rows(key):
    (light, moderate, vigorous), epoch, column = QUOTED_COUNTS[key]
    row = lookup(key)
    assert (row.light, row.moderate, row.vigorous) == (light, moderate, vigorous)
    assert row.epoch_s == epoch and row.column == column and row.counts
    assert row.doi
    checked = key in ARTICLE_ABSTRACTS
    assert ("not yet checked" in row.transcribed_from) != checked
    assert (row.table == "abstract (Results)") == checked and bool(row.page) == checked
    # counts add up over time: thresholds scale with the epoch (mg thresholds do not)
    five = row.scaled(5.0)
    assert five.moderate == pytest.approx(moderate * 5.0 / epoch)
    assert lookup("vahaypya2015_mad_hip").scaled(5.0) == lookup("vahaypya2015_mad_hip")


def test_every_registry_row_is_quoted():
    assert set(registry()) == set(QUOTED) | set(QUOTED_COUNTS)


def test_metrics_and_columns():
    assert lookup("vahaypya2015_mad_hip").column == "mad_mg"
    assert {r.metric for r in registry().values()} == {"ENMO", "MAD", "COUNTS_AXIS1", "COUNTS_VM"}
    assert all(r.column == "enmo_mg" for r in registry().values() if r.metric == "ENMO")


def test_thresholds_increase():
    for r in registry().values():
        vals = [v for v in (r.light, r.moderate, r.vigorous) if v is not None]
        assert vals == sorted(vals) and len(set(vals)) == len(vals), r.key


def test_bands_of_a_row():
    b = lookup("hildebrand_adults_geneactiv_wrist").bands()
    assert b == {"light": (45.8, 93.2), "moderate": (93.2, 418.3), "mvpa": (93.2, None),
                 "vigorous": (418.3, None)}
    assert "light" not in lookup("vahaypya2015_mad_hip").bands()


def test_unknown_key_names_the_known_ones():
    with pytest.raises(ValueError, match="unknown cut-point set 'nope'.*hildebrand_adults"):
        lookup("nope")
