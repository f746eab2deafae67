"""Differential tests of the BehaviorTree.CPP v4 built-ins added after the first set:
``Precondition``, ``Switch2`` .. ``Switch6``, ``AsyncSequence``, ``AsyncFallback``,
``UnsetBlackboard``, ``SkipUnlessUpdated``, ``WaitValueUpdate`` and ``WasEntryUpdated``,
against BehaviorTree.CPP itself (``behaviortreepy``, BT.CPP 4.8) with the harness of
``test_differential_btcpp.py``: the root's status, every node's status and the status changes
after every tick, the integer entries, and where given other entries (``outputs``).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

import pytest
import test_differential_btcpp as differential
from test_differential_btcpp import BLACKBOARD, VARS, TreeGen, check, diff, doc

STR = {"v": "string"}
#: a guard for a ReactiveSequence: true, true, false, true ... (halts what follows on tick 3)
GUARD = '<ScriptedSync name="g_SSFS"/>'

# name -> (body, outputs read after each tick, subtrees T1, T2...)
CASES: dict[str, tuple] = {
    # -- Precondition -----------------------------------------------------------------------
    "precondition_true_runs_the_child": (
        '<Precondition name="p" if="c0 == 0"><Scripted name="x_RRS"/></Precondition>',
        {},
    ),
    "precondition_false_default_failure": (
        '<Precondition name="p" if="c0 == 1"><Scripted name="x_RS"/></Precondition>',
        {},
    ),
    "precondition_else_success_skipped_running": (
        '<Sequence name="s"><Precondition name="p1" if="false" else="SUCCESS">'
        '<Scripted name="x_S"/></Precondition><Precondition name="p2" if="false" '
        'else="SKIPPED"><Scripted name="y_S"/></Precondition><Precondition name="p3" '
        'if="c0 &gt; 2" else="RUNNING"><AlwaysSuccess name="z"/></Precondition>'
        '<Script name="a" code="c0 += 1"/></Sequence>',
        {},
    ),
    "precondition_not_rechecked_while_the_child_runs": (
        '<Precondition name="p" if="c1 == 0"><Sequence name="s">'
        '<Script name="a" code="c1 := 1"/><Scripted name="x_RRS"/></Sequence></Precondition>',
        {},
    ),
    "precondition_after_a_halt_skips_the_check": (
        f'<ReactiveSequence name="r">{GUARD}<Precondition name="p" if="c1 == 0">'
        '<Sequence name="s"><Script name="a" code="c1 := 1"/><Scripted name="x_RRRS"/>'
        "</Sequence></Precondition></ReactiveSequence>",
        {},
    ),
    "precondition_child_failure": (
        '<Precondition name="p" if="true"><Scripted name="x_RF"/></Precondition>',
        {},
    ),
    "precondition_else_from_the_blackboard": (
        # (BT.CPP refuses text in the NodeStatus entry from SetBlackboard or a script; a
        # SubTree's literal port is text it converts when the port reads it)
        '<SubTree name="st" ID="T1" st="SKIPPED"/>',
        {},
        '<Sequence name="s"><Precondition name="p" if="false" else="{st}">'
        '<AlwaysSuccess name="x"/></Precondition><Scripted name="y_RS"/></Sequence>',
    ),
    "precondition_runtime_script_error": (
        '<Precondition name="p" if="missing_entry == 1"><AlwaysSuccess name="x"/></Precondition>',
        {},
    ),
    # -- Switch -----------------------------------------------------------------------------
    "switch2_literal_matches_second_case": (
        '<Switch2 name="w" variable="b" case_1="a" case_2="b">'
        '<Scripted name="x_S"/><Scripted name="y_RS"/><Scripted name="z_F"/></Switch2>',
        {},
    ),
    "switch3_default": (
        '<Switch3 name="w" variable="q" case_1="a" case_2="b" case_3="c"><AlwaysFailure name="x"/>'
        '<AlwaysFailure name="y"/><AlwaysFailure name="z"/><Scripted name="d_RS"/></Switch3>',
        {},
    ),
    "switch_int_entry_changes_halts_the_running_child": (
        '<Sequence name="s"><Script name="a" code="c0 += 1; sw := c0"/><Switch3 name="w" '
        'variable="{sw}" '
        'case_1="1" case_2="2" case_3="4"><Scripted name="x_RRS"/><Scripted name="y_RRRS"/>'
        '<Scripted name="z_RS"/><Scripted name="d_RRS"/></Switch3></Sequence>',
        {},
    ),
    "switch_string_entry_and_case_from_the_blackboard": (
        '<Sequence name="s"><SetBlackboard name="b" output_key="m" value="fly"/>'
        '<Script name="a" code="k := \'fly\'"/><Switch2 name="w" variable="{m}" case_1="land" '
        'case_2="{k}"><AlwaysFailure name="x"/><Scripted name="y_RS"/><AlwaysFailure name="d"/>'
        "</Switch2></Sequence>",
        {},
    ),
    "switch_script_number_matches_text_cases": (
        '<Sequence name="s"><Script name="a" code="v := 1.5; n := 3"/><Switch4 name="w" '
        'variable="{v}" case_1="2" case_2="1" case_3="1.5" case_4="x"><Scripted name="a1_S"/>'
        '<Scripted name="a2_S"/><Scripted name="a3_S"/><Scripted name="a4_S"/>'
        '<Scripted name="d_F"/></Switch4><Switch2 name="w2" variable="{n}" case_1="3.000000" '
        'case_2="3"><Scripted name="b1_S"/><Scripted name="b2_F"/><Scripted name="d2_F"/>'
        "</Switch2></Sequence>",
        {},
    ),
    "switch_missing_variable_entry_takes_the_default": (
        '<Switch2 name="w" variable="{nope}" case_1="" case_2="0"><AlwaysFailure name="x"/>'
        '<AlwaysFailure name="y"/><Scripted name="d_RS"/></Switch2>',
        {},
    ),
    "switch_missing_case_entry_never_matches": (
        '<Sequence name="s"><Script name="a" code="sw := c0"/><Switch2 name="w" variable="0" '
        'case_1="{nope}" case_2="{sw}"><AlwaysFailure name="x"/><Scripted name="y_RS"/>'
        '<AlwaysFailure name="d"/></Switch2></Sequence>',
        {},
    ),
    "switch_without_ports_takes_the_default": (
        '<Switch2 name="w"><AlwaysFailure name="x"/><AlwaysFailure name="y"/>'
        '<Scripted name="d_S"/></Switch2>',
        {},
    ),
    "switch_skipped_child": (
        '<Sequence name="s"><Switch2 name="w" variable="1" case_1="1" case_2="2">'
        '<AlwaysSuccess name="x" _skipIf="true"/><AlwaysFailure name="y"/>'
        '<AlwaysFailure name="d"/></Switch2><Scripted name="z_RS"/></Sequence>',
        {},
    ),
    "switch_halted_by_a_reactive_parent": (
        f'<ReactiveSequence name="r">{GUARD}<Script name="a" code="sw := c0"/>'
        '<Switch2 name="w" variable="{sw}" case_1="0" '
        'case_2="1"><Scripted name="x_RRRS"/><Scripted name="y_S"/><Scripted name="d_S"/>'
        "</Switch2></ReactiveSequence>",
        {},
    ),
    # BT.CPP compares with std::stoi / std::stod on a leading part of the texts
    "switch_numeric_quirks": (
        '<Sequence name="s">'
        + "".join(
            f'<Switch2 name="w{i}" variable="{a}" case_1="{b}" case_2="zzz">'
            f'<AlwaysSuccess name="m{i}"/><AlwaysSuccess name="o{i}"/>'
            f'<ForceSuccess name="f{i}"><AlwaysFailure name="d{i}"/></ForceSuccess></Switch2>'
            for i, (a, b) in enumerate(
                (
                    ("1.5", "1"),
                    ("0x10", "0"),
                    (" 1", "1"),
                    ("+1", "1"),
                    ("1e3", "1000"),
                    ("3000000000", "3000000000.0"),
                    ("nan", "nan"),
                    ("inf", "INF"),
                    ("2abc", "2"),
                    ("-0", "0"),
                    (".5", "0.5"),
                    ("1.00000001", "1"),
                    ("0x10", "16"),
                    (".1000002", ".1"),
                    ("1e-310", "0"),
                )
            )
        )
        + "</Sequence>",
        {},
    ),
    "switch6": (
        '<Sequence name="s"><Script name="a" code="sw := c2; c2 += 1"/><Switch6 name="w" '
        'variable="{sw}" case_1="5" case_2="4" case_3="3" case_4="2" case_5="1" case_6="0">'
        + "".join(f'<Scripted name="x{k}_S"/>' for k in range(7))
        + "</Switch6></Sequence>",
        {},
    ),
    # -- AsyncSequence / AsyncFallback --------------------------------------------------------
    "async_sequence_instant_children": (
        '<AsyncSequence name="s"><AlwaysSuccess name="a"/><Script name="b" code="c0 += 1"/>'
        '<AlwaysSuccess name="c"/></AsyncSequence>',
        {},
    ),
    "async_sequence_yields_to_a_reactive_guard": (
        f'<ReactiveSequence name="r">{GUARD}<AsyncSequence name="s">'
        '<Script name="a" code="c0 += 1"/><Scripted name="x_RS"/><Script name="b" '
        'code="c1 += 1"/><Scripted name="y_S"/></AsyncSequence></ReactiveSequence>',
        {},
    ),
    "async_sequence_failure_and_skips": (
        '<AsyncSequence name="s"><AlwaysSuccess name="a" _skipIf="true"/><Scripted name="x_SF"/>'
        '<AlwaysSuccess name="b"/><Scripted name="y_RF"/></AsyncSequence>',
        {},
    ),
    "async_sequence_all_skipped": (
        '<Sequence name="q"><AsyncSequence name="s"><AlwaysSuccess name="a" _skipIf="true"/>'
        '<AlwaysFailure name="b" _skipIf="true"/></AsyncSequence><Scripted name="z_RS"/></Sequence>',
        {},
    ),
    "async_fallback_instant_children": (
        '<AsyncFallback name="f"><AlwaysFailure name="a"/><Script name="b" code="c0 += 1" '
        '_failureIf="c0 &gt; 100"/><ScriptCondition name="c" code="c0 &gt; 2"/>'
        '<AlwaysSuccess name="d"/></AsyncFallback>',
        {},
    ),
    "async_fallback_yields_to_a_reactive_guard": (
        f'<ReactiveSequence name="r">{GUARD}<AsyncFallback name="f">'
        '<AlwaysFailure name="a"/><Scripted name="x_RF"/><AlwaysFailure name="b"/>'
        '<Scripted name="y_RS"/></AsyncFallback></ReactiveSequence>',
        {},
    ),
    "async_in_a_repeat": (
        '<Repeat name="r" num_cycles="3"><AsyncFallback name="f"><AlwaysFailure name="a"/>'
        '<AsyncSequence name="s"><Script name="b" code="c0 += 1"/><AlwaysSuccess name="c"/>'
        "</AsyncSequence></AsyncFallback></Repeat>",
        {},
    ),
    # -- UnsetBlackboard ---------------------------------------------------------------------
    "unset_removes_an_entry": (
        '<Sequence name="s"><Script name="a" code="v := \'x\'"/>'
        '<ScriptedSync name="g_SF"/><UnsetBlackboard name="u" key="v"/></Sequence>',
        STR,
    ),
    "unset_missing_entry_succeeds": (
        '<Sequence name="s"><UnsetBlackboard name="u" key="nope"/><Scripted name="x_RS"/></Sequence>',
        {},
    ),
    "unset_key_from_an_entry": (
        '<Sequence name="s"><Script name="a" code="v := \'x\'; k := \'v\'"/>'
        '<UnsetBlackboard name="u" key="{k}"/><Scripted name="x_RS"/></Sequence>',
        STR,
    ),
    "unset_then_read_raises": (
        '<Sequence name="s"><Script name="a" code="v := \'x\'"/><UnsetBlackboard name="u" '
        'key="v"/><ScriptCondition name="c" code="v == \'x\'"/></Sequence>',
        STR,
    ),
    "unset_in_a_subtree_leaves_remapped_entries": (
        '<Sequence name="s"><Script name="a" code="v := \'x\'"/>'
        '<SubTree name="st" ID="T1" w="{v}"/><SubTree name="st2" ID="T2" _autoremap="true"/>'
        "</Sequence>",
        STR,
        '<Sequence name="s1"><UnsetBlackboard name="u1" key="w"/>'
        '<UnsetBlackboard name="u2" key="@v"/><Scripted name="x_RS"/></Sequence>',
        '<Sequence name="s2"><UnsetBlackboard name="u3" key="v"/><Script name="b" '
        'code="mine := 1"/><UnsetBlackboard name="u4" key="mine"/><Scripted name="y_RS"/>'
        "</Sequence>",
    ),
    # -- SkipUnlessUpdated / WaitValueUpdate / WasEntryUpdated -------------------------------
    "skip_unless_updated_entry_set_before": (
        '<Sequence name="s"><SkipUnlessUpdated name="u" entry="{c0}"><Scripted name="x_S"/>'
        '</SkipUnlessUpdated><Script name="a" code="c1 += 1"/></Sequence>',
        {},
    ),
    "skip_unless_updated_every_other_tick": (
        '<Sequence name="s"><Fallback name="f"><ScriptedSync name="g_FS"/>'
        '<Script name="w" code="c0 += 1"/></Fallback><SkipUnlessUpdated name="u" entry="c0">'
        '<Scripted name="x_SF"/></SkipUnlessUpdated></Sequence>',
        {},
    ),
    "skip_unless_updated_running_child_goes_on": (
        '<Sequence name="s"><SkipUnlessUpdated name="u" entry="{c0}"><Scripted name="x_RRS"/>'
        '</SkipUnlessUpdated><Script name="a" code="c1 += 1"/></Sequence>',
        {},
    ),
    "skip_unless_updated_missing_entry_then_created": (
        '<Sequence name="s"><Script name="a" code="c0 += 1"/><Fallback name="f">'
        '<ScriptCondition name="c" code="c0 &lt; 3"/><Script name="b" code="z := c0"/>'
        '</Fallback><SkipUnlessUpdated name="u" entry="{z}"><Scripted name="x_S"/>'
        "</SkipUnlessUpdated></Sequence>",
        {},
    ),
    "wait_value_update": (
        '<Sequence name="s"><Fallback name="f"><ScriptedSync name="g_FFS"/>'
        '<Script name="w" code="c0 += 1"/></Fallback><WaitValueUpdate name="u" entry="{c0}">'
        '<Scripted name="x_RS"/></WaitValueUpdate></Sequence>',
        {},
    ),
    "wait_value_update_in_parallel": (
        '<Parallel name="p" success_count="-1"><Sequence name="s"><Script name="w" '
        'code="c1 += 1"/><Scripted name="k_RRRS"/><Script name="w2" code="c0 += 1"/></Sequence>'
        '<WaitValueUpdate name="u" entry="{c0}"><Scripted name="x_S"/></WaitValueUpdate>'
        '<Scripted name="y_RRRRRS"/></Parallel>',
        {},
    ),
    "wait_value_update_halted_keeps_its_child_running": (
        f'<ReactiveSequence name="r">{GUARD}<Script name="w" code="c0 += 1"/>'
        '<WaitValueUpdate name="u" entry="{c0}"><Scripted name="x_RRRRS"/></WaitValueUpdate>'
        "</ReactiveSequence>",
        {},
    ),
    "skip_unless_updated_halted_while_child_runs": (
        f'<ReactiveSequence name="r">{GUARD}<Script name="w" code="c0 += 1"/>'
        '<SkipUnlessUpdated name="u" entry="{c0}"><Scripted name="x_RRRRS"/>'
        "</SkipUnlessUpdated></ReactiveSequence>",
        {},
    ),
    "was_entry_updated": (
        '<Sequence name="s"><Fallback name="f"><ScriptedSync name="g_FSS"/>'
        '<SetBlackboard name="w" output_key="c0" value="1"/></Fallback>'
        '<ForceSuccess name="fs"><WasEntryUpdated name="u" entry="{c0}"/></ForceSuccess>'
        '<ForceSuccess name="fs2"><WasEntryUpdated name="u2" entry="nope"/></ForceSuccess>'
        "</Sequence>",
        {},
    ),
    "was_entry_updated_unset_and_recreated_reuses_ids": (
        '<Sequence name="s"><UnsetBlackboard name="x" key="q"/><Script name="a" code="q := 1"/>'
        '<ForceSuccess name="fs"><WasEntryUpdated name="u" entry="{q}"/></ForceSuccess>'
        '<Script name="b" code="q2 := 1"/><Script name="b2" code="q2 := 2"/>'
        '<ForceSuccess name="fs2"><WasEntryUpdated name="u2" entry="q2"/></ForceSuccess>'
        "</Sequence>",
        {},
    ),
    "updated_by_an_output_port": (
        '<LoopInt name="l" queue="1;2;3" value="{c1}"><Sequence name="s">'
        '<ForceSuccess name="fs"><WasEntryUpdated name="u" entry="{c1}"/></ForceSuccess>'
        '<ForceSuccess name="fs2"><WasEntryUpdated name="u2" entry="{c1}"/></ForceSuccess>'
        "</Sequence></LoopInt>",
        {},
    ),
    "updated_through_a_subtree": (
        '<Sequence name="s"><Fallback name="f"><ScriptedSync name="g_FS"/>'
        '<Script name="w" code="c0 += 1"/></Fallback>'
        '<SubTree name="st" ID="T1" inner="{c0}" lit="5"/></Sequence>',
        {},
        '<Sequence name="s1"><SkipUnlessUpdated name="u" entry="{inner}"><Scripted name="x_S"/>'
        '</SkipUnlessUpdated><ForceSuccess name="fs"><WasEntryUpdated name="u2" entry="lit"/>'
        "</ForceSuccess></Sequence>",
    ),
}


@pytest.fixture(scope="module", autouse=True)
def _close_peer():
    """Close the BT.CPP worker process this module shares with test_differential_btcpp."""
    yield
    if differential._PEER:
        differential._PEER.pop().close()


@pytest.mark.parametrize("case", sorted(CASES))
def test_builtin_matches_btcpp(case: str) -> None:
    body, outputs, *subtrees = CASES[case]
    check(doc(body, *subtrees), ticks=12, blackboard=dict(BLACKBOARD), outputs=outputs)


class MoreTreeGen(TreeGen):
    """Random trees as in test_differential_btcpp, with the new controls and decorators.

    ``Switch`` reads ``{sw}``, which scripts copy from the integer entries (BT.CPP refuses
    a text port on an entry typed int before the tree is built); ``SkipUnlessUpdated`` /
    ``WaitValueUpdate`` / ``WasEntryUpdated`` watch them.
    """

    def control(self, depth: int, room: int) -> ET.Element:
        r = self.rng
        pick = r.random()
        if pick < 0.5:
            return super().control(depth, room)
        if pick < 0.75:
            el = self._new(r.choice(("AsyncSequence", "AsyncFallback")))
            for _ in range(r.randint(1, max(1, min(4, room - 1)))):
                el.append(self.node(depth + 1))
            return el
        n = r.randint(2, 3)
        el = self._new(f"Switch{n}")
        if r.random() < 0.9:
            el.set("variable", "{sw}")
        for k in range(1, n + 1):
            if r.random() < 0.9:
                el.set(f"case_{k}", str(r.randint(-1, 3)))
        for _ in range(n + 1):
            el.append(self.node(depth + 1))
        return el

    def subtree(self, depth: int) -> ET.Element:
        el = super().subtree(depth)
        if el.get("_autoremap") is None:  # (btrun refuses a SubTree reading {sw} unpassed)
            el.set("sw", "{sw}")
        return el

    def decorator(self, depth: int) -> ET.Element:
        r = self.rng
        if r.random() < 0.5:
            return super().decorator(depth)
        tag = r.choice(("Precondition", "SkipUnlessUpdated", "WaitValueUpdate"))
        el = self._new(tag)
        if tag == "Precondition":
            el.set("if", self.cond())
            if r.random() < 0.6:
                el.set("else", r.choice(("SUCCESS", "FAILURE", "SKIPPED", "RUNNING")))
        else:
            var = r.choice(VARS)
            el.set("entry", "{" + var + "}" if r.random() < 0.7 else var)
        el.append(self.node(depth + 1))
        return el

    def leaf(self) -> ET.Element:
        r = self.rng
        if r.random() < 0.1:  # the entry the Switches read (see the module's note)
            el = self._new("Script")
            el.set("code", f"sw := {r.choice(VARS)}")
            return el
        if r.random() < 0.1:
            el = self._new("WasEntryUpdated")
            el.set("entry", "{" + r.choice(VARS) + "}")
            return el
        return super().leaf()


SEEDS = range(70_000, 70_400)
NEW = {
    "AsyncSequence",
    "AsyncFallback",
    "Switch2",
    "Switch3",
    "Precondition",
    "SkipUnlessUpdated",
    "WaitValueUpdate",
    "WasEntryUpdated",
}


def test_random_trees_with_the_new_builtins_match_btcpp() -> None:
    failures = []
    for seed in SEEDS:
        xml = MoreTreeGen(seed).xml()
        problem = diff(xml)
        if problem is not None:
            failures.append(f"seed {seed}: {problem}\n{xml}")
    assert not failures, f"{len(failures)} trees differ; first:\n{failures[0]}"


def test_random_trees_use_every_new_builtin() -> None:
    seen = {el.tag for seed in SEEDS for el in ET.fromstring(MoreTreeGen(seed).xml()).iter()}
    assert seen >= NEW
