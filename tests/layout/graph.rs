//! The file-level import graph: its strongly connected components (the circles) and the
//! shortest loop through each, for the failure message.

use std::collections::{BTreeMap, BTreeSet};

use super::rust::*;
pub(super) type Edges = BTreeMap<ModKey, BTreeMap<ModKey, (usize, String)>>;

/// The strongly connected components of more than one file (Tarjan).
pub(super) fn strongly_connected(tree: &Tree, edges: &Edges) -> Vec<Vec<ModKey>> {
    struct State<'a> {
        edges: &'a Edges,
        index: BTreeMap<ModKey, usize>,
        low: BTreeMap<ModKey, usize>,
        stack: Vec<ModKey>,
        on_stack: BTreeSet<ModKey>,
        next: usize,
        out: Vec<Vec<ModKey>>,
    }
    fn visit(st: &mut State, v: &ModKey) {
        st.index.insert(v.clone(), st.next);
        st.low.insert(v.clone(), st.next);
        st.next += 1;
        st.stack.push(v.clone());
        st.on_stack.insert(v.clone());
        let targets: Vec<ModKey> = st
            .edges
            .get(v)
            .map(|m| m.keys().cloned().collect())
            .unwrap_or_default();
        for w in &targets {
            if !st.index.contains_key(w) {
                visit(st, w);
                let lw = st.low[w];
                let lv = st.low.get_mut(v).expect("visited");
                *lv = (*lv).min(lw);
            } else if st.on_stack.contains(w) {
                let iw = st.index[w];
                let lv = st.low.get_mut(v).expect("visited");
                *lv = (*lv).min(iw);
            }
        }
        if st.low[v] == st.index[v] {
            let mut scc = Vec::new();
            while let Some(w) = st.stack.pop() {
                st.on_stack.remove(&w);
                let done = w == *v;
                scc.push(w);
                if done {
                    break;
                }
            }
            if scc.len() > 1 {
                scc.sort();
                st.out.push(scc);
            }
        }
    }
    let mut st = State {
        edges,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on_stack: BTreeSet::new(),
        next: 0,
        out: Vec::new(),
    };
    for v in tree.files.keys() {
        if !st.index.contains_key(v) {
            visit(&mut st, v);
        }
    }
    st.out.sort();
    st.out
}

/// A shortest cycle through the first file of a strongly connected component, as a closed walk
/// (first = last), by breadth-first search inside the component.
pub(super) fn shortest_cycle(scc: &[ModKey], edges: &Edges) -> Vec<ModKey> {
    let members: BTreeSet<&ModKey> = scc.iter().collect();
    let start = &scc[0];
    let mut prev: BTreeMap<ModKey, ModKey> = BTreeMap::new();
    let mut queue = std::collections::VecDeque::from([start.clone()]);
    while let Some(v) = queue.pop_front() {
        for w in edges.get(&v).into_iter().flat_map(|m| m.keys()) {
            if !members.contains(w) {
                continue;
            }
            if w == start {
                let mut walk = vec![v.clone()];
                let mut cur = v.clone();
                while cur != *start {
                    cur = prev[&cur].clone();
                    walk.push(cur.clone());
                }
                walk.reverse();
                walk.push(start.clone());
                return walk;
            }
            if !prev.contains_key(w) && w != start {
                prev.insert(w.clone(), v.clone());
                queue.push_back(w.clone());
            }
        }
    }
    vec![start.clone()]
}
