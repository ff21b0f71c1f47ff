"""The original's LDBAs (Owl HOA) as tensors and the evaluation-only tracker on them.

References: Spot parsing the same HOA text (structure) and Spot's own translation of each
formula (language), and a plain-Python walk of the HOA text (accepting-visit counts).
"""

import functools
import json
import re
from importlib import resources
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import spot

import buddy  # isort: skip  (importable once spot has put its own directory on sys.path)

from specrl_jax import specs
from specrl_jax.automata import compile_suite, product, zero_or_one
from specrl_jax.eval import original_ldba as ol
from specrl_jax.tasks.sources import AutomatonSource

EPS_AP = "eps__"


def _entries() -> list[tuple[str, int, str, str]]:
    with resources.files("specrl_jax.specs").joinpath("data", "original_ldbas.json").open() as f:
        data = json.load(f)
    return [(suite, i, e["formula"], e["hoa"])
            for suite, entries in data["suites"].items() for i, e in enumerate(entries)]


ENTRIES = _entries()
ENTRIES_BY_KEY = {(s, i): hoa for s, i, _, hoa in ENTRIES}


def world(suite: str) -> SimpleNamespace:
    """The propositions and alphabet of the suite's world (as `env.propositions/alphabet`)."""
    info = specs.suite_info(suite)
    if info.alphabet == "per_agent_zero_or_one":
        alphabet = product(zero_or_one(4), zero_or_one(4))
    else:
        alphabet = zero_or_one(len(info.propositions))
    return SimpleNamespace(propositions=info.propositions, alphabet=alphabet)


@functools.cache
def built(suite: str, index: int) -> ol.OriginalLDBA:
    env = world(suite)
    return ol.build_ldba(ENTRIES_BY_KEY[suite, index], env.propositions, env.alphabet)



# --------------------------------------------------------------------------------------------
# structure and language against Spot


def spot_with_epsilon_ap(hoa: str) -> spot.twa_graph:
    """Spot reads the HOA once epsilon lines become edges labelled by a fresh AP."""
    count = int(re.search(r"^AP: (\d+)", hoa, re.MULTILINE).group(1))
    hoa = re.sub(r"^AP: \d+", f"AP: {count + 1}", hoa, flags=re.MULTILINE)
    hoa = re.sub(r"^(AP: .*)$", rf'\1 "{EPS_AP}"', hoa, count=1, flags=re.MULTILINE)
    hoa = re.sub(r"^\[(.*)\] ", rf"[(\1) & !{count}] ", hoa, flags=re.MULTILINE)
    hoa = re.sub(r"^(\d+)$", rf"[{count}] \1", hoa, flags=re.MULTILINE)
    return spot.automaton(hoa)


def minterm(aut: spot.twa_graph, names, values, eps: bool) -> buddy.bdd:
    out = buddy.bdd_ithvar(aut.register_ap(EPS_AP)) if eps else buddy.bdd_nithvar(
        aut.register_ap(EPS_AP))
    for name, value in zip(names, values):
        var = aut.register_ap(name)
        out = out & (buddy.bdd_ithvar(var) if value else buddy.bdd_nithvar(var))
    return out


@pytest.mark.parametrize("suite,index", [(s, i) for s, i, _, _ in ENTRIES])
def test_tensors_match_spot_parse(suite, index):
    """Every (state, symbol): the Spot edge the symbol satisfies (at most one: Owl's labelled
    edges are deterministic) is our next state and acceptance; Spot's epsilon-AP edges are our
    epsilon successors; same start state."""
    env, ldba = world(suite), built(suite, index)
    aut = spot_with_epsilon_ap(ENTRIES_BY_KEY[suite, index])
    names = [str(ap) for ap in aut.ap() if str(ap) != EPS_AP]
    cols = [env.propositions.index(n) for n in names]
    delta, acc = np.asarray(ldba.delta), np.asarray(ldba.accepting)
    epsilon = np.asarray(ldba.epsilon)
    assert int(ldba.init) == aut.get_init_state_number()
    assert aut.num_states() == delta.shape[0]
    eps_only = buddy.bdd_ithvar(aut.register_ap(EPS_AP))
    for q in range(aut.num_states()):
        edges = list(aut.out(q))
        for a, row in enumerate(np.asarray(env.alphabet)):
            m = minterm(aut, names, row[cols], eps=False)
            hits = [e for e in edges if (e.cond & m) != buddy.bddfalse]
            assert len(hits) <= 1
            assert delta[q, a] == (hits[0].dst if hits else -1)
            assert acc[q, a] == (bool(hits) and hits[0].acc.has(0))
        spot_eps = sorted(e.dst for e in edges if e.cond == eps_only)
        assert sorted(t for t in epsilon[q] if t >= 0) == spot_eps


def _aut_from_tensors(ldba: ol.OriginalLDBA, props) -> spot.twa_graph:
    """A Spot automaton of our tensors with the epsilon edges folded in (q -a-> delta[r, a] for
    every r in q's epsilon closure): the LDBA's language over the alphabet."""
    bdict = spot.make_bdd_dict()
    aut = spot.make_twa_graph(bdict)
    aut.set_buchi()
    aut.prop_state_acc(False)
    variables = [aut.register_ap(p) for p in props]
    delta, acc = np.asarray(ldba.delta), np.asarray(ldba.accepting)
    closure = np.asarray(ldba.closure)
    aut.new_states(delta.shape[0])
    aut.set_init_state(int(ldba.init))
    for q, r in zip(*np.nonzero(closure)):
        for a, row in enumerate(np.asarray(ldba.alphabet)):
            if delta[r, a] < 0:
                continue
            cond = buddy.bddtrue
            for var, value in zip(variables, row):
                cond = cond & (buddy.bdd_ithvar(var) if value else buddy.bdd_nithvar(var))
            aut.new_edge(int(q), int(delta[r, a]), cond, [0] if acc[r, a] else [])
    return aut


def _allowed(props, alphabet) -> str:
    rows = []
    for row in np.asarray(alphabet):
        rows.append("(" + " & ".join(p if v else f"!{p}" for p, v in zip(props, row)) + ")")
    return "G(" + " | ".join(rows) + ")"


@pytest.mark.parametrize("suite,index", sorted({(s, i) for s, i, f, _ in ENTRIES
                                                if not s.startswith("arm")}))
def test_language_equals_formula(suite, index):
    """The tensors accept exactly the formula's words over the alphabet (Spot's translation of
    `formula & G allowed`); arm suites repeat the Zone formulas and are left out."""
    env, ldba = world(suite), built(suite, index)
    formula = next(f for s, i, f, _ in ENTRIES if (s, i) == (suite, index))
    ours = _aut_from_tensors(ldba, env.propositions)
    text = f"({formula}) & {_allowed(env.propositions, env.alphabet)}"
    reference = spot.translate(spot.formula(text), "Buchi", dict=ours.get_dict())
    assert spot.are_equivalent(ours, reference)


# --------------------------------------------------------------------------------------------
# counts against a plain-Python walk of the HOA text


def python_edges(hoa: str) -> tuple[int, list[str], dict[int, list]]:
    """Owl HOA read line by line: state -> [(python label expression or None, dst, acc)]."""
    start = int(re.search(r"^Start: (\d+)", hoa, re.MULTILINE).group(1))
    names = re.findall(r'"([^"]*)"', re.search(r"^AP: .*$", hoa, re.MULTILINE).group(0))
    edges, state = {}, None
    for line in hoa.split("--BODY--")[1].split("--END--")[0].strip().splitlines():
        if line.startswith("State:"):
            state = int(line.split()[1])
            edges[state] = []
        elif line.startswith("["):
            label, rest = line[1:].split("]")
            words = {"!": " not ", "&": " and ", "|": " or ", "t": "True", "f": "False"}
            expr = re.sub(r"\d+|[!&|tf]",
                          lambda m: words.get(m.group(0), f"v[{m.group(0)}]"), label)
            edges[state].append((expr, int(rest.split()[0]), "{0}" in rest))
        else:
            edges[state].append((None, int(line), False))
    return start, names, edges


def python_walk(hoa: str, props, word, jumps) -> tuple[int, bool]:
    """DeepLTL's tracker: labels read by the first satisfied edge (no edge: the sink), the
    unique epsilon edge taken at each step in `jumps` or as soon as one exists afterwards; a
    run that dies while the run that never jumped lives falls back to it (our task's rule)."""
    start, names, edges = python_edges(hoa)
    q, free, count, want = start, start, 0, False

    def read(state, v):
        if state is None:
            return None, False
        nxt = [(d, a) for e, d, a in edges.get(state, []) if e is not None and eval(e, {"v": v})]
        return nxt[0] if nxt else (None, False)

    for t, label in enumerate(word):
        want = want or t in jumps
        eps = [d for e, d, _ in edges.get(q, []) if e is None] if q is not None else []
        if want and eps:
            q, want = eps[0], False
        v = [label[props.index(n)] for n in names]
        (q, acc), (free, acc_free) = read(q, v), read(free, v)
        if q is None and free is not None:
            q, acc, want = free, acc_free, False
        count += acc
    return count, q is None


def tracker_count(ldba, word_symbols, epsilon_flags, rule):
    def body(tracker, x):
        symbol, eps = x
        tracker, accepted = ol.step(ldba, tracker, symbol, eps, rule=rule)
        return tracker, accepted

    tracker, accepted = jax.lax.scan(body, ol.init(ldba), (word_symbols, epsilon_flags))
    return tracker, accepted


_count = jax.jit(tracker_count, static_argnames="rule")


def sticky_word(rng, num_symbols: int, length: int, stay: float = 0.7) -> np.ndarray:
    """Symbols held for geometric durations, like an agent dwelling in a zone."""
    word = [int(rng.integers(num_symbols))]
    for _ in range(length - 1):
        word.append(word[-1] if rng.random() < stay else int(rng.integers(num_symbols)))
    return np.asarray(word, np.int32)


@pytest.mark.parametrize("suite", ["letter/infinite/rsp", "letter/infinite/rec",
                                   "zone/infinite/rsp", "zone/infinite/per",
                                   "multi_agent_zone/infinite/rsp"])
def test_policy_counts_match_python_walk(suite):
    """Random sticky words, our epsilon steps inserted at two random times: the tracker's visits
    and death equal the plain-Python walk that takes the jumps at the same labels (an epsilon
    step consumes no label). Half the words use only labels the start state reads, so that
    persistence runs fall back after a jump and jump again."""
    rng = np.random.default_rng(7)
    env = world(suite)
    alphabet = np.asarray(env.alphabet)
    for index in range(3):
        ldba, hoa = built(suite, index), ENTRIES_BY_KEY[suite, index]
        read_at_start = np.flatnonzero(np.asarray(ldba.delta)[int(ldba.init)] >= 0)
        for labels in (np.arange(alphabet.shape[0]), read_at_start) * 2:
            word = labels[sticky_word(rng, len(labels), 40)]
            jumps = np.sort(rng.choice(41, 2, replace=False))
            symbols = np.insert(word, jumps, 0)  # label of an epsilon step is not read
            flags = np.zeros(len(symbols), bool)
            flags[jumps + np.arange(2)] = True
            tracker, accepted = _count(ldba, jnp.asarray(symbols), jnp.asarray(flags), "policy")
            count, dead = python_walk(hoa, env.propositions, [alphabet[s] for s in word],
                                      set(jumps.tolist()))
            assert int(tracker.visits) == count == int(np.asarray(accepted).sum())
            assert (int(ol.state(tracker)) == -1) == dead


def test_hindsight_is_the_best_jump_time():
    """'hindsight' = max over every jump time of the Python walk, on the Zone and multi-agent
    persistence automata (one epsilon edge each), and it never counts less than 'policy'."""
    rng = np.random.default_rng(3)
    for suite in ("zone/infinite/per", "multi_agent_zone/infinite/per"):
        env = world(suite)
        alphabet = np.asarray(env.alphabet)
        for index in range(3):
            ldba, hoa = built(suite, index), ENTRIES_BY_KEY[suite, index]
            for _ in range(5):
                word = sticky_word(rng, alphabet.shape[0], 30, stay=0.85)
                best = max(python_walk(hoa, env.propositions, [alphabet[s] for s in word], {t})[0]
                           for t in range(-1, len(word)))
                none = jnp.zeros(len(word), bool)
                tracker, _ = _count(ldba, jnp.asarray(word), none, "hindsight")
                assert int(tracker.visits) == best
                policy, _ = _count(ldba, jnp.asarray(word), none, "policy")
                assert int(policy.visits) <= best


def test_hand_counted_words():
    """Hand-counted visits. Zone response (G F blue & G(blue -> F green) & G!(yellow|magenta)):
    Owl's automaton accepts on the first non-blue step and on every green that answers a blue.
    Zone persistence (F G yellow & ...): one visit per yellow step after the jump; leaving
    yellow after it falls back to the run that never jumped (state 0), no violation."""
    none, blue, green, magenta, yellow = range(5)
    rsp = built("zone/infinite/rsp", 0)
    word = [none, blue, none, green, green, blue, green]
    tracker, accepted = _count(rsp, jnp.asarray(word), jnp.zeros(7, bool), "policy")
    assert np.asarray(accepted).tolist() == [True, False, False, True, False, False, True]
    assert not bool(ol.is_violated(rsp, tracker))
    tracker, _ = _count(rsp, jnp.asarray([blue, magenta, green]), jnp.zeros(3, bool), "policy")
    assert int(tracker.visits) == 0 and bool(ol.is_violated(rsp, tracker))

    per = built("zone/infinite/per", 0)  # F G yellow
    symbols = jnp.asarray([none, yellow, 0, yellow, yellow, none, yellow])
    flags = jnp.asarray([False, False, True, False, False, False, False])
    tracker, accepted = _count(per, symbols, flags, "policy")
    assert np.asarray(accepted).tolist() == [False, False, False, True, True, False, False]
    assert not bool(ol.is_violated(per, tracker)) and int(ol.state(tracker)) == 0
    # hindsight: the three yellow labels in a row (our epsilon step reads none) from a jump
    # before the first of them; the run that stayed in state 0 is still alive
    tracker, _ = _count(per, symbols, flags, "hindsight")
    assert int(tracker.visits) == 3 and not bool(ol.is_violated(per, tracker))


def test_pending_jump_waits_for_an_epsilon_edge():
    """FG blue & F(yellow & F green) (the reference's own example): our jump at the start is
    taken by the original only once yellow then green have been seen."""
    props = ("blue", "green", "magenta", "yellow")
    hoa = ("HOA: v1\nStart: 0\nacc-name: Buchi\nAcceptance: 1 Inf(0)\nAP: 3 \"blue\" \"yellow\" "
           "\"green\"\n--BODY--\nState: 0\n[!1] 0\n[1 & !2] 3\n[1 & 2] 1\nState: 3\n[!2] 3\n"
           "[2] 1\nState: 1\n[t] 1\n2\nState: 2\n[0] 2 {0}\n--END--\n")
    ldba = ol.build_ldba(hoa, props, zero_or_one(4))
    none, blue, green, _, yellow = range(5)
    symbols = jnp.asarray([0, blue, yellow, blue, green, blue, blue, none])
    flags = jnp.asarray([True] + [False] * 7)
    tracker, accepted = _count(ldba, symbols, flags, "policy")
    assert np.asarray(accepted).tolist() == [False] * 5 + [True, True, False]
    # leaving blue kills the jumped run: back to the run that never jumped, waiting in state 1
    assert int(ol.state(tracker)) == 1 and not bool(ol.is_violated(ldba, tracker))
    tracker, _ = _count(ldba, symbols[1:], flags[1:], "policy")  # no jump of ours: none here
    assert int(tracker.visits) == 0


def test_fall_back_keeps_counting_on_ours_and_the_original_after_a_wrong_jump():
    """`F G a & G !b` on our automaton (`AutomatonSource`) and on an Owl-shaped original: leaving
    'a' after the jump falls back on both, re-entering and jumping again counts again on both;
    'b' violates ours and kills the original's runs, which count nothing afterwards."""
    props = ("a", "b", "c")
    alphabet = zero_or_one(3)  # rows: none, a, b, c
    none, a, b = alphabet[0], alphabet[1], alphabet[2]
    hoa = ("HOA: v1\nStart: 0\nacc-name: Buchi\nAcceptance: 1 Inf(0)\nAP: 2 \"a\" \"b\"\n"
           "--BODY--\nState: 0\n[!1] 0\n1\nState: 1\n[0 & !1] 1 {0}\n--END--\n")
    ldba = ol.build_ldba(hoa, props, alphabet)
    source = AutomatonSource(compile_suite(["F G a & G !b"], props, alphabet),
                             jnp.asarray(alphabet))
    task, tracker = source.reset(jax.random.key(0), None, jnp.int32(0)), ol.init(ldba)
    step_ours, step_original = jax.jit(source.step), jax.jit(ol.step)
    word = [a, "eps", a, a, none, a, "eps", a, a, b]
    ours, original, label = [], [], none
    for item in word:
        is_eps = isinstance(item, str)
        label = label if is_eps else item
        task, events = step_ours(jax.random.key(1), task, jnp.asarray(label), None,
                                 jnp.asarray(is_eps), jnp.int32(0))
        tracker, accepted = step_original(ldba, tracker, jnp.asarray(label), jnp.asarray(is_eps))
        ours.append((bool(events.accepted), bool(events.violation)))
        original.append((bool(accepted), bool(ol.is_violated(ldba, tracker)),
                         int(ol.state(tracker))))
    counted = [False, False, True, True, False, False, False, True, True, False]
    assert [acc for acc, _ in ours] == [acc for acc, _, _ in original] == counted
    assert [v for _, v in ours] == [v for _, v, _ in original] == [False] * 9 + [True]
    assert [q for *_, q in original] == [0, 1, 1, 1, 0, 0, 1, 1, 1, -1]
    assert int(tracker.visits) == 4  # DeepLTL's committed run: 2, dead at the first `none`
    for item, is_eps in ((a, False), (None, True), (a, False)):
        tracker, accepted = ol.step(ldba, tracker, jnp.asarray(a if item is None else item),
                                    jnp.asarray(is_eps))
        assert not bool(accepted)
    assert int(tracker.visits) == 4


def test_shipped_epsilon_edges_leave_a_deterministic_initial_part():
    """What the fall-back relies on, on every shipped LDBA with epsilon edges (persistence):
    they leave the start state only, the one state labels reach from it, which has no accepting
    edge, loops on every label it reads and reads exactly the labels that begin some word of
    the formula (so the run that never jumped dies exactly on a violation); labels never lead
    back from an epsilon target, which has no epsilon edge."""
    with_epsilon = [(s, i, f) for s, i, f, _ in ENTRIES if (built(s, i).epsilon >= 0).any()]
    assert len(with_epsilon) == 9 and all(s.endswith("/per") for s, _, _ in with_epsilon)
    for suite, index, formula in with_epsilon:
        env, ldba = world(suite), built(suite, index)
        start, delta = int(ldba.init), np.asarray(ldba.delta)
        epsilon = np.asarray(ldba.epsilon)[:, 0]
        assert np.flatnonzero(epsilon >= 0).tolist() == [start]
        assert set(delta[start].tolist()) <= {start, -1}
        assert not np.asarray(ldba.accepting)[start].any()
        targets = np.flatnonzero(np.asarray(ldba.closure)[epsilon[start]])
        assert (delta[targets] != start).all() and (epsilon[targets] < 0).all()
        for symbol, row in enumerate(np.asarray(env.alphabet)):
            first = " & ".join(p if v else f"!{p}" for p, v in zip(env.propositions, row))
            text = f"({formula}) & {_allowed(env.propositions, env.alphabet)} & {first}"
            assert (delta[start, symbol] >= 0) == (not spot.translate(text).is_empty())


# --------------------------------------------------------------------------------------------
# suites, stacks, validation


def test_suite_stacks_and_vmap():
    """suite_ldbas stacks the suite's automata in suite order; a vmapped step over the stack
    equals each member stepped alone; method suites without original automata give None; a
    None entry is a dead placeholder that counts nothing."""
    env = world("letter/infinite/rsp")
    stacked = ol.suite_ldbas("letter/infinite/rsp", env)
    assert stacked.delta.shape[0] == 3 and bool(stacked.present.all())
    assert ol.suite_formulas("letter/infinite/rsp") == specs.suite("letter/infinite/rsp")
    assert ol.suite_ldbas("deepltl/letter/infinite", env) is None
    formulas = specs.suite("letter/infinite/rec")[:1] + ["G F a"] + specs.suite(
        "letter/infinite/rsp")[2:]
    some = ol.formula_ldbas(formulas, env)
    assert np.asarray(some.present).tolist() == [True, False, True]
    np.testing.assert_array_equal(np.asarray(some.delta[2]), np.asarray(stacked.delta[2]))
    word = jnp.asarray(sticky_word(np.random.default_rng(0), 13, 25))
    flags = jnp.zeros(25, bool)
    batched = jax.vmap(lambda l: _count(l, word, flags, "policy")[0].visits)(stacked)
    for i in range(3):
        assert int(batched[i]) == int(_count(built("letter/infinite/rsp", i), word, flags,
                                             "policy")[0].visits)
    mixed = ol.stack_ldbas([None, built("letter/infinite/rec", 0)], env.alphabet)
    props = jnp.asarray(np.asarray(env.alphabet)[word])
    visits = jax.vmap(lambda l: _count(l, props, flags, "policy")[0].visits)(mixed)
    assert int(visits[0]) == 0 and not bool(mixed.present[0])
    assert int(visits[1]) == int(_count(built("letter/infinite/rec", 0), word, flags,
                                        "policy")[0].visits)


def test_validation():
    hoa = ENTRIES_BY_KEY["zone/infinite/rec", 0]
    with pytest.raises(ValueError, match="not world propositions"):
        ol.build_ldba(hoa, ("a", "b", "c", "d"), zero_or_one(4))
    with pytest.raises(ValueError, match="alphabet must be"):
        ol.build_ldba(hoa, ("blue", "green", "magenta", "yellow"), zero_or_one(3))
    with pytest.raises(ValueError, match="Buchi"):
        ol.build_ldba(hoa.replace("1 Inf(0)", "2 Inf(0)&Inf(1)"),
                      ("blue", "green", "magenta", "yellow"), zero_or_one(4))
    with pytest.raises(ValueError, match="no original automata"):
        ol.suite_formulas("zone/finite/ind")
    ldba = built("zone/infinite/rec", 0)
    with pytest.raises(ValueError, match="rule must be"):
        ol.step(ldba, ol.init(ldba), jnp.int32(0), False, rule="eager")


def test_every_shipped_automaton_is_deterministic_with_one_epsilon_edge_at_most():
    """What the 'policy' rule relies on (the original asserts a unique epsilon edge)."""
    for suite, index, _, _ in ENTRIES:
        ldba = built(suite, index)
        assert ldba.epsilon.shape[1] == 1
        assert bool(ldba.present)
    per = built("zone/infinite/per", 0)
    assert np.asarray(per.violating).tolist() == [False, False]
    assert np.asarray(per.epsilon).ravel().tolist() == [1, -1]
