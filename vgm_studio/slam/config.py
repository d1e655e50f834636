"""Typed configuration of a SLAM run: front end, validation, back end and maps."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from vgm_studio.core.cpus import usable_threads
from vgm_studio.graph.config import GraphConfig
from vgm_studio.maps.config import MapConfig
from vgm_studio.matching.reference_labels import LabelThresholds
from vgm_studio.model.registry import VALIDATOR_MODELS

# ``none`` keeps every edge, the model validators come from the model registry, ``reference``
# keeps the edges that land on the reference pose.
ValidatorName = str
VALIDATORS: tuple[str, ...] = ("none", *VALIDATOR_MODELS, "reference")


@dataclass(frozen=True)
class FrontEndConfig:
    """Keyframes, sequential edges and the loop-candidate search.

    Attributes:
        keyframe_distance: A new keyframe after this much travel, metres.
        keyframe_angle_deg: …or after this much rotation, degrees.
        loop_radius: Where the graph is certain, loop candidates lie within this distance in
            the current estimate, metres; the window grows with the graph's uncertainty
            between the two keyframes (``slam.loop_search``).
        loop_max_angle_deg: …and within this heading difference, degrees, widened by three σ
            of the heading (``turned_loops_per_keyframe`` more are searched beyond it).
        loop_gate: Window candidates pass a Mahalanobis gate at this χ²(2) probability.
        window_linear: (min, max) half-width of a loop's search window in x and y, metres:
            three σ of the relative position, clamped.
        window_angular_deg: (min, max) half-width in heading, degrees.
        place_candidates: Place-recognition candidates per keyframe that the window search
            found none for (0: none).
        place_candidates_drifted: …and per keyframe whose window is clamped smaller than
            three σ of the drift: the estimate has lost track of where it is, so more of the
            descriptor's neighbours are worth a search (in a long corridor the right place
            is often second or third: the infinite corridor went from 0.34 to 0.06 m with 3).
        place_max_distance: …whose Scan Context column-shift distance is at most this
            (0 same, 1 nothing in common).
        place_angular_deg: Half-width in heading of a place candidate's window around the
            descriptor's yaw guess, degrees.
        place_max_angle_deg: …and whose yaw (the descriptor's guess of the turn between
            the two) is at most this, degrees.
        place_trail: Place recognition also describes each keyframe by its trail: its scan
            and those of the keyframes on the last this-many metres of its path, placed by the
            estimate (0: by its scan alone). One 180° scan of a corridor looks like many
            others; the doors and turns of the path that led there tell them apart (CSAIL: the
            right place first 1.7× as often), but only where the robot came the same way, so
            the scan's own candidates are kept too.
        drift_sigma_xy: How far a kept sequential edge may be off, as the loop search sees it,
            metres (added to the matcher's covariance). The graph's own floors
            (``GraphConfig``) weight edges against each other and are far wider than a
            scan matcher drifts, which would make every window the widest.
        drift_sigma_theta_deg: …and in heading, degrees.
        drift_odometry_sigma_xy: How far the odometry of a rejected sequential step may be
            off, as the loop search sees it, metres per metre (the graph's own fallback,
            ``GraphConfig.odometry_sigma_xy``, is far wider); also the graph's σ of a step
            whose odometry the slide check confirmed, and of one joined at a match the
            validator was only unsure of (``sequential_unsure``).
        drift_odometry_sigma_theta_deg: …and in heading, degrees.
        prefer_estimate: A loop is first matched in the smallest window around the estimate;
            the full window's pose replaces it only if it scores this much higher (relative):
            along a corridor or past a row of doors the full window holds poses that score
            nearly as well as the right one.
        loop_min_score: The loop matcher searches only poses whose correlative score (mean
            likelihood under the scan, 0..1) reaches this; a pair that does not overlap then
            fails at once instead of being searched pose by pose (with no bound to prune on,
            branch and bound over a 6 m window visits every pose).
        sequential_submap: Sequential edges are matched against a submap of this many last
            keyframes (correlative search in the smallest loop window, then refinement);
            0 matches scan to scan (kiss-icp from odometry, then refinement). The submap
            measured better: Intel 0.0290 m against 0.0301 m, simulated office 0.0165 m
            against 0.0186 m, for ~8% more time.
        sequential_retry: A sequential match the validator rejected is matched again over the
            wide window (around the odometry's step and around standing still) and replaced
            by a wide match the validator keeps. Only with ``sequential_submap``.
        sequential_slide_check: A kept sequential match that ended further from the
            odometry's step than the smallest window's half-width (in x or y) is matched
            across it and its neighbour, and goes out where that match agrees with the
            odometry instead (``SequentialMatcher.check_slides``). Only with
            ``sequential_submap``. It mends the slides it is meant for (freiburg-campus
            0.106 → 0.092 m, Belgioioso 0.060 → 0.052 m). When it also checked matches
            turned out of the window, it took right matches out for odometry steps 9–14°
            off along the infinite corridor (0.059 → 0.32 m); translation alone, 0.059.
        sequential_unsure: A sequential match the validator rejected at or above this
            p(success) (unsure of it, not sure it is wrong) that lies in the smallest window
            around its odometry step joins its keyframes at the match's pose, weighted as the
            odometry a slide check confirmed (``drift_odometry_sigma_*``; the wide σ where a
            wide match the validator kept says the odometry is off), not by the wide
            fallback around the odometry's step (``slam.factors.fallback_edge``); None: every
            rejected match falls back. A validator meets its unsure steps where it meets a
            building it never saw: CSAIL with its fold model 0.085 → 0.060 m, with the
            bundled model's logit lowered by 2 0.092 → 0.084 m; the bundled model 0.058 →
            0.057 m (the infinite corridor 0.073 → 0.063, freiburg-campus 0.074 → 0.071,
            Örebro 0.054 → 0.055).
            0.02 is where ``SecondLook``'s unsure band begins: below it the validator is sure
            the match is wrong, and the step goes to the odometry.
        sequential_odometry: A sequential step joined at its match (kept, or unsure of) is
            the match and its odometry step fused, each by its information: the odometry's
            translation at ``drift_odometry_sigma_xy``, the match at its covariance plus the
            spread of its score's surface (``matching.response``), so that along a corridor,
            where a match could slide, the odometry holds the step (``slam.factors
            .sequential_edge``). Not where the two headings differ by more than three
            ``drift_odometry_sigma_theta_deg`` or the scans rule the odometry out (below).
            Acapulco's steps slid 0.2–0.5 m along its corridors where kiss-icp's odometry was
            within centimetres: 0.062 → 0.057 m; freiburg-campus 0.073 → 0.066, the infinite
            corridor 0.054 → 0.046, the other rows within 1 mm or better.
        sequential_odometry_share: …and only where the scans at the odometry's step keep at
            least this share of the match's score: without it a kiss-icp step 0.7 m off on
            Belgioioso's turns in place was taken in part (0.039 → 0.045 m).
        sequential_wide_angular_deg: Half-width in heading of that wide window, degrees (in
            x and y it is the widest loop window). A 180° scanner turned by more than 90°
            keeps less than half of its view, too little to match; keyframes are at most
            ``keyframe_angle_deg`` apart by odometry, but a lost odometry can miss any turn.
        sequential_retry_gain: …and a wide match is only tried on the validator if it puts
            this much more of the scan (inlier share) on the keyframe before it than the
            rejected one: along a corridor the wide window holds poses that fit nearly as
            well as the right one.
        sequential_pairwise_gain: Where the submap search scores nothing in the smallest
            window, the pairwise matcher's answer stands in for it; an answer outside that
            window is taken only where the submap scores it (best near it, in the smallest
            window) this much higher (mean likelihood under the scan) than the best near the
            odometry's step, else the step has no match (the odometry joins it, and the
            wide window is searched again). Where the scans see little, a point-to-point fit
            of two scans slides along the walls it has, and the validator, judging the pair
            alone, believes it (freiburg-campus held out, keyframes 873–876, at a turn on the
            spot: 0.7–3.7 m off at p 0.79–0.97, the submap scoring them no better than the
            odometry's step); where the answer is right, the submap agrees (CSAIL: 0.38–0.75
            against 0.22–0.29). None: every answer is taken.
        submap_keyframes: A loop is matched against a submap of its target keyframe and this
            many keyframes on each side of it.
        loop_min_gap: …and at least this many keyframes earlier.
        loops_per_keyframe: The nearest this many candidates of each keyframe are matched.
        turned_loops_per_keyframe: …and this many more among the keyframes turned further
            than ``loop_max_angle_deg`` from it: a corridor driven back the other way shares
            its side walls, and the submap around the target saw what lies behind the robot
            (CSAIL: most revisits are 90–170° turned).
        turned_overlap: A window loop turned further than ``loop_max_angle_deg`` that the
            validator rejected is kept where at least this share of b's trail (b and its
            last ``submap_keyframes`` keyframes, placed by the estimate) lies on a's submap
            at the loop's estimate; it then needs support in the consistency check like a
            place loop (None: off; only with a model validator, whatever cut the network's
            p faced: ``loop_threshold`` and ``loop_precision`` are cuts on that p, to which
            the network here is blind). Two 180° scans of a corridor driven both ways
            share little more than its side walls, so the network, which judges the two
            scans, cannot tell a right turned loop from a wrong one (ROC AUC 0.64–0.70 on
            FHW's and CSAIL's turned loops), while the two local maps overlap where the
            loop is right (AUC 0.94–0.97 on FHW, CSAIL and Belgioioso).
        turned_max_reach: …and only where three σ of where b may be relative to a (in x and
            y, from the drift) is at most this, metres. Farther, the estimate may have slid
            by more than a corridor's period, and a trail placed by it overlaps an alias as
            well as the place: the infinite corridor with a validator made unsure (its logit
            2 lower) kept 14 turned loops 9 m along and ended 0.417 m off, 0.058 m judged so.
            Not at the widest window (3 m): a fold model on CSAIL, which never saw it, then
            lost the right turned loops of its corridors' U-turns, 0.060 → 0.124 m (0.060
            judged so).
        block: Keyframes added between two updates of the running estimate: the validator
            and the incremental solver work on whole blocks.
        final_sweep: After the last block, search once more, from the final estimate, the
            revisits the run never closed (``loop_search.unclosed_candidates``): a revisit met
            before the loops that straighten the map went in was searched where the
            estimate then put it. Its loops face the validator and the consistency check as
            any window loop does.
        false_loops: Deliberately wrong loop closures to inject (robustness tests in the style
            of Sünderhauf and Protzel): pairs of keyframes at least ``false_loop_distance``
            apart, matched from a guess that claims they are at the same place.
        false_loop_distance: How far apart the keyframes of an injected loop are at least, in
            the odometry estimate, metres.
        seed: Seeds the injected loops.
        threads: Threads that match a block's loops at once (0: ``OMP_NUM_THREADS`` where
            set, else the CPUs this process may use, at most 4). Results do not depend on it.
    """

    keyframe_distance: float = 0.5
    keyframe_angle_deg: float = 20.0
    loop_radius: float = 3.0
    loop_max_angle_deg: float = 60.0
    loop_gate: float = 0.99
    window_linear: tuple[float, float] = (0.3, 3.0)
    window_angular_deg: tuple[float, float] = (10.0, 30.0)
    place_candidates: int = 1
    place_candidates_drifted: int = 3
    place_max_distance: float = 0.35
    place_angular_deg: float = 15.0
    place_max_angle_deg: float = 180.0
    place_trail: float = 10.0
    drift_sigma_xy: float = 0.005
    drift_sigma_theta_deg: float = 0.03
    drift_odometry_sigma_xy: float = 0.05
    drift_odometry_sigma_theta_deg: float = 2.0
    prefer_estimate: float = 0.1
    loop_min_score: float = 0.3
    sequential_submap: int = 5
    sequential_retry: bool = True
    sequential_slide_check: bool = True
    sequential_unsure: float | None = 0.02
    sequential_odometry: bool = True
    sequential_odometry_share: float = 0.8
    sequential_wide_angular_deg: float = 90.0
    sequential_retry_gain: float = 0.1
    sequential_pairwise_gain: float | None = 0.1
    submap_keyframes: int = 5
    loop_min_gap: int = 20
    loops_per_keyframe: int = 2
    turned_loops_per_keyframe: int = 1
    turned_overlap: float | None = 0.7
    turned_max_reach: float = 6.0
    block: int = 25
    final_sweep: bool = True
    false_loops: int = 0
    false_loop_distance: float = 5.0
    seed: int = 0
    threads: int = 0

    def match_threads(self) -> int:
        """``threads``, or where it is 0 the threads this process may use
        (``core.cpus.usable_threads``)."""
        return self.threads or usable_threads()


@dataclass(frozen=True)
class ValidationConfig:
    """Which edges go into the graph.

    Attributes:
        validator: ``none`` keeps every edge; ``vgmnet``, ``rgb-baseline`` and ``score`` ask a
            trained model (``model``); ``reference`` keeps edges whose estimate lands on the
            reference relative pose (the upper bound).
        model: Checkpoint of the model validators.
        loop_threshold: p(success) a loop edge needs (never below the checkpoint's own
            threshold); None: the checkpoint's. That threshold was chosen for accuracy, but a
            graph pays far more for one false loop than for a missed one, and loops are many.
        loop_precision: A loop edge also needs p(success) at or above the lowest cut whose
            validation precision (the checkpoint's curve) reaches this; None: not asked.
            With ``loop_threshold`` too, a loop must pass both: the higher cut wins.
        thresholds: What ``reference`` calls a success (only successes are kept).
        batch_size: Edges per forward pass of the model.
        second_look: A network validator looks again at the edges it is unsure of (p between
            0.02 and 0.98), its logits averaged over the pair turned this many ways
            (``model.validator.SecondLook``; 1: off). On the eleven buildings' loops, each
            judged by a model that never saw its building, it took the mean accuracy from
            0.949 to 0.954 and lowered none; but averaging pulls a sure-ish loop's p down
            under ``loop_threshold``, which was set on single looks: freiburg-campus kept 420
            loops instead of 492 and went from 0.088 to 0.114 m. So it is off by default.
    """

    validator: ValidatorName = "vgmnet"
    model: Path | None = None
    loop_threshold: float | None = 0.8
    loop_precision: float | None = None
    thresholds: LabelThresholds = field(default_factory=LabelThresholds)
    batch_size: int = 64
    second_look: int = 1


@dataclass(frozen=True)
class ConsistencyConfig:
    """The group-consistency check of loops (``slam.consistency``): the pairwise test and
    the vote.

    Attributes:
        enabled: Run the check (off: every loop the validator kept goes in).
        probability: The χ²(3) gate of a cycle is its quantile at this probability.
        estimate_weight: The running estimate counts as this many loops for the loops within
            its widened gate (``overconfidence``). Its covariance is the graph's own (wide)
            one, so by default it vetoes what the graph is sure of: a group of aliased loops
            (a corridor matched one door along or back to front, a symmetric hall matched to
            its mirror) agrees with itself and would outvote it.
        likely_weight: …and as this many for the loops within its gate: a run of more agreeing
            loops than this (beyond those the gate holds) just past the gate outvotes it.
        overconfidence: How many times its σ the estimate may be wrong by, without a gross
            error: the graph's σ comes from the matchers' covariances, which a wrong match
            kept at a tight covariance makes too small. Loops the gate of the σ widened this
            much cannot explain are vetoed however many agree.
        min_support: A loop that moves the map by more than the scan matchers drift, or one
            from place recognition, is kept only in a group of more than this many agreeing
            loops near it (itself counted; 0: alone too; see ``support_sigma``), and only
            where the loops it outvoted hold no rival group of more than this many that is at
            least half its size. A revisit after long drift yields a run of loops from
            consecutive keyframes; one convincing alias in a corridor yields one, a periodic
            corridor a rival run.
        support_sigma: …and the agreeing loops count as support only where the drift puts
            their ends within this of the loop's ends (one σ, metres): the cycle test of two
            loops then tells apart a loop from one ~3.4 σ off (its χ²(3) 99% gate), less than
            a corridor's door spacing. Between far ends it passes because the chain could
            bend either way, which says nothing.
    """

    enabled: bool = True
    probability: float = 0.99
    estimate_weight: int = 1000
    likely_weight: int = 3
    overconfidence: float = 2.0
    min_support: int = 1
    support_sigma: float = 0.5


@dataclass(frozen=True)
class SlamConfig:
    """Everything a SLAM run depends on."""

    front_end: FrontEndConfig = field(default_factory=FrontEndConfig)
    validation: ValidationConfig = field(default_factory=ValidationConfig)
    consistency: ConsistencyConfig = field(default_factory=ConsistencyConfig)
    graph: GraphConfig = field(default_factory=GraphConfig)
    maps: MapConfig = field(default_factory=MapConfig)
