/* A fixed-order variable-order Markov predictor, VOM(k), online from empty: the speed
 * anchor of slearn's benchmarks, written for them (bench/peers.py compiles and loads it).
 *
 * Input: tokens O A O A ... O (int32). Step i (1..n) predicts O_i from the contexts
 * A_i (order 0), O_{i-1} A_i (order 1), ..., O_{i-k} A_{i-k+1} ... O_{i-1} A_i (order k):
 * the longest one already seen speaks, with its most frequent outcome (ties: the most
 * recent); nothing seen: -1. Then step i is counted: every context of order 0..k gets one
 * more occurrence of O_i.
 *
 * Contexts form a trie read backwards from A_i; its edges and the per-context outcome
 * counts share one open-addressing table keyed by (parent, kind, token), kept at most half
 * full and doubled when needed.
 *
 * Build: cc -O2 -shared -fPIC -o libvom.so vom.c
 */
#include <stdint.h>
#include <stdlib.h>

typedef struct {
    int64_t *keys;     /* -1 = empty slot */
    int32_t *values;   /* node id (context child) or outcome id */
    int64_t slots, used;
    int32_t *best;     /* per node: most frequent outcome, -1 none */
    int64_t *best_count;
    int64_t nodes, node_cap;
    int64_t *count;    /* per outcome record */
    int64_t outcomes, outcome_cap;
} model_t;

static uint64_t mix(uint64_t h) {
    h = (h ^ (h >> 31)) * 0x7FB5D329728EA185ULL;
    h = (h ^ (h >> 27)) * 0x81DADEF4BC2DD44DULL;
    return h ^ (h >> 33);
}

static int64_t key_of(int64_t parent, int64_t kind, int64_t token) {
    return (parent << 32) | (kind << 31) | token;
}

static int32_t find(const model_t *m, int64_t key) {
    uint64_t mask = (uint64_t)m->slots - 1, s = mix((uint64_t)key) & mask;
    while (m->keys[s] != -1) {
        if (m->keys[s] == key) return m->values[s];
        s = (s + 1) & mask;
    }
    return -1;
}

static int rehash(model_t *m) {
    int64_t slots = 2 * m->slots;
    int64_t *keys = malloc(slots * sizeof *keys);
    int32_t *values = malloc(slots * sizeof *values);
    if (!keys || !values) { free(keys); free(values); return -1; }
    for (int64_t s = 0; s < slots; s++) keys[s] = -1;
    for (int64_t s = 0; s < m->slots; s++) {
        if (m->keys[s] == -1) continue;
        uint64_t t = mix((uint64_t)m->keys[s]) & (uint64_t)(slots - 1);
        while (keys[t] != -1) t = (t + 1) & (uint64_t)(slots - 1);
        keys[t] = m->keys[s];
        values[t] = m->values[s];
    }
    free(m->keys); free(m->values);
    m->keys = keys; m->values = values; m->slots = slots;
    return 0;
}

static int grow_nodes(model_t *m) {
    int64_t cap = 2 * m->node_cap;
    int32_t *best = realloc(m->best, cap * sizeof *best);
    if (!best) return -1;
    m->best = best;
    int64_t *best_count = realloc(m->best_count, cap * sizeof *best_count);
    if (!best_count) return -1;
    m->best_count = best_count;
    for (int64_t i = m->node_cap; i < cap; i++) { best[i] = -1; best_count[i] = 0; }
    m->node_cap = cap;
    return 0;
}

static int grow_outcomes(model_t *m) {
    int64_t cap = 2 * m->outcome_cap;
    int64_t *count = realloc(m->count, cap * sizeof *count);
    if (!count) return -1;
    for (int64_t i = m->outcome_cap; i < cap; i++) count[i] = 0;
    m->count = count; m->outcome_cap = cap;
    return 0;
}

/* The id under key, or a new node (is_outcome 0) or outcome record; -1 out of memory. */
static int32_t find_or_add(model_t *m, int64_t key, int is_outcome) {
    if (2 * (m->used + 1) > m->slots && rehash(m) < 0) return -1;
    uint64_t mask = (uint64_t)m->slots - 1, s = mix((uint64_t)key) & mask;
    while (m->keys[s] != -1) {
        if (m->keys[s] == key) return m->values[s];
        s = (s + 1) & mask;
    }
    int32_t id;
    if (is_outcome) {
        if (m->outcomes == m->outcome_cap && grow_outcomes(m) < 0) return -1;
        id = (int32_t)m->outcomes++;
    } else {
        if (m->nodes == m->node_cap && grow_nodes(m) < 0) return -1;
        id = (int32_t)m->nodes++;
    }
    m->keys[s] = key; m->values[s] = id; m->used++;
    return id;
}

static int count_outcome(model_t *m, int32_t node, int32_t outcome) {
    int32_t r = find_or_add(m, key_of(node, 1, outcome), 1);
    if (r < 0) return -1;
    int64_t c = ++m->count[r];
    if (c >= m->best_count[node]) { m->best_count[node] = c; m->best[node] = outcome; }
    return 0;
}

static int32_t predict(const model_t *m, const int32_t *obs_act, int64_t i, int32_t order) {
    /* obs_act[2j] = O_j, obs_act[2j-1] = A_j */
    int32_t node = find(m, key_of(0, 0, obs_act[2 * i - 1]));
    if (node < 0) return -1;
    int32_t deepest = node;
    for (int64_t j = 1; j <= order && i - j >= 0; j++) {
        if (j >= 2 && (node = find(m, key_of(node, 0, obs_act[2 * (i - j + 1) - 1]))) < 0) break;
        if ((node = find(m, key_of(node, 0, obs_act[2 * (i - j)]))) < 0) break;
        deepest = node;
    }
    return m->best[deepest];
}

static int learn(model_t *m, const int32_t *obs_act, int64_t i, int32_t order) {
    int32_t y = obs_act[2 * i];
    int32_t node = find_or_add(m, key_of(0, 0, obs_act[2 * i - 1]), 0);
    if (node < 0 || count_outcome(m, node, y) < 0) return -1;
    for (int64_t j = 1; j <= order && i - j >= 0; j++) {
        if (j >= 2 && (node = find_or_add(m, key_of(node, 0, obs_act[2 * (i - j + 1) - 1]), 0)) < 0)
            return -1;
        if ((node = find_or_add(m, key_of(node, 0, obs_act[2 * (i - j)]), 0)) < 0) return -1;
        if (count_outcome(m, node, y) < 0) return -1;
    }
    return 0;
}

static void release(model_t *m) {
    free(m->keys); free(m->values); free(m->best); free(m->best_count); free(m->count);
}

/* Predict then learn every step; predicted[i - 1] is step i's guess. Returns the number
 * of steps, or -1 when memory ran out. */
int64_t vom_run(const int32_t *tokens, int64_t n_tokens, int32_t order, int32_t *predicted) {
    model_t m = {0};
    m.slots = 1 << 12; m.node_cap = 1 << 10; m.outcome_cap = 1 << 10;
    m.keys = malloc(m.slots * sizeof *m.keys);
    m.values = malloc(m.slots * sizeof *m.values);
    m.best = malloc(m.node_cap * sizeof *m.best);
    m.best_count = malloc(m.node_cap * sizeof *m.best_count);
    m.count = calloc(m.outcome_cap, sizeof *m.count);
    if (!m.keys || !m.values || !m.best || !m.best_count || !m.count) { release(&m); return -1; }
    for (int64_t s = 0; s < m.slots; s++) m.keys[s] = -1;
    for (int64_t i = 0; i < m.node_cap; i++) { m.best[i] = -1; m.best_count[i] = 0; }
    m.nodes = 1; /* the root */
    int64_t steps = n_tokens > 0 ? (n_tokens - 1) / 2 : 0;
    for (int64_t i = 1; i <= steps; i++) {
        predicted[i - 1] = predict(&m, tokens, i, order);
        if (learn(&m, tokens, i, order) < 0) { release(&m); return -1; }
    }
    release(&m);
    return steps;
}
