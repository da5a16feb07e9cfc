#include "core/scene_keys_doc.hpp"

#include <span>
#include <string_view>
#include <vector>

#include <fmt/format.h>

#include "core/scene_keys.hpp"

namespace cfddem {

namespace {

struct SectionText {
  KeySection section;
  std::string_view title; // Markdown
  std::string_view intro; // Markdown before the table ("" = none)
  std::string_view outro; // Markdown after the table ("" = none)
};

constexpr SectionText kSections[] = {
    {KeySection::DomainParticles, "Domain and particles", "", ""},
    {KeySection::Contacts, "Contacts and time step", "", ""},
    {KeySection::Partition, "Partition (ORB, ranks)", "", ""},
    {KeySection::RunOutput, "Run and output", "",
     "Outputs are described in [outputs.md](outputs.md)."},
    {KeySection::Fluid, "Gas (`[fluid]`)",
     "A scene without a `[fluid]` table has no gas and does no fluid work. With one, these keys\n"
     "apply (models: [theory.md](theory.md) §4-§7, §9):",
     "Checked when the run starts (exit code 2, naming the key): cells that do not tile the "
     "domain,\ninflow without an outflow or pointing out of the domain, a pressure drop on a "
     "non-periodic axis,\n`fluid.cfl` above its stable limit; on R ranks, a gas box narrower "
     "than 3 cells."},
};

constexpr std::string_view kIntro = R"(# Scene keys

<!-- Generated: `cfddem keys --markdown` prints this file from the key table in
core/scene_keys.cpp and the prose in core/scene_keys_doc.cpp. Edit those, then run
`cmake --build build --target docs_keys`; test_core fails while this file differs. -->

A scene is a TOML file. Every key below can also be given on the command line as `key=value`
after the scene file (`cfddem run scenes/hcs.toml dem.restitution=0.9`); the value is read as
TOML, and a bare word that is not TOML is a string (`dem.scheme=islands` is
`dem.scheme='"islands"'`); spaces around the `=` of one quoted argument are dropped
(`'run.end_time = 0.1'`). `cfddem check SCENE [key=value ...]` prints every key with its
resolved value and the derived numbers (particle mass, tau_p, dt, solid fraction, Haff time...)
without running anything.

Errors: an unknown key (named with the nearest known key), a value of the wrong type, a number
outside "allowed" or a word not in it stops before anything is written, with a message naming the
key (exit code 2).

The parser (`core/scene.cpp`) takes each key's default, allowed range and words from the same
table this page is printed from, and refuses any key that is not in it. `cfddem --help` lists
the keys in short, `cfddem keys` with their meanings. "required" means the scene is refused
without it; "generator" marks the keys that place particles when there is no `particles.file`.
)";

constexpr std::string_view kOutro = R"(## Command line

```
cfddem run   [SCENE.toml] [key=value ...] [--threads N] [--out DIR] [--quiet] [--restart FILE]
             [--overwrite]
cfddem check [SCENE.toml] [key=value ...]
cfddem keys  [--markdown]
cfddem --help
cfddem --version
```

A run directory that holds another run's outputs is refused unless `--overwrite` is given, which
removes those outputs first; `name` cannot leave `runs/`. A restart may change only
@RESTART_KEYS@ (the run's name, end and outputs, and the gas drive: settle a bed with the gas at
rest, then turn the gas on from the checkpoint); any other changed key is refused by name. This
list is the rule the restart applies (core/scene_keys.cpp). See
[hostile_input.md](hostile_input.md) for exit codes, warnings and faults.

Without a scene file `cfddem run` runs the built-in HCS (1222 particles generated in place,
30 ms). `--threads N`: TBB threads per rank (default `OMP_NUM_THREADS`, else the cores
available). `--restart FILE`: continue from a checkpoint of the same scene (see
[outputs.md](outputs.md)). Exit codes: 0 done, 2 configuration error, 3 the run stopped (NaN,
an overlap beyond `dem.max_overlap`, a particle moving more than a radius in one step or leaving
through a wall, omega dt >= 2), with the particle, time and cause.
)";

std::string_view type_word(KeyType t) {
  switch (t) {
  case KeyType::String:
    return "string";
  case KeyType::Integer:
    return "integer";
  case KeyType::Number:
    return "number";
  case KeyType::Bool:
    return "bool";
  case KeyType::Vec3:
    return "[x, y, z]";
  case KeyType::Bool3:
    return "[bool, bool, bool]";
  case KeyType::Int3:
    return "[nx, ny, nz] integers";
  }
  return "";
}

// A default value as the docs show it: the shortest decimal that reads back exactly; a word as
// code.
std::string shown(const KeyDefault::Value& v) {
  const std::string text = toml_text(v, true);
  return std::holds_alternative<std::string_view>(v) ? fmt::format("`{}`", text) : text;
}

// Markdown cells of one key.
std::string default_md(const SceneKey& k) {
  const KeyDefault& d = k.fallback;
  switch (d.kind) {
  case KeyDefault::Kind::Required:
    return d.text.empty() ? "required" : fmt::format("required {}", d.text);
  case KeyDefault::Kind::Value:
    return d.text.empty() ? shown(d.value) : std::string(d.text);
  case KeyDefault::Kind::SameAs:
    return fmt::format("`{}`", d.text);
  case KeyDefault::Kind::Derived:
    return std::string(d.text);
  }
  return "";
}

std::string allowed_md(const SceneKey& k) {
  if (k.choices.empty())
    return range_text(k);
  std::string out;
  for (std::string_view c : k.choices)
    out += fmt::format("{}`\"{}\"`", out.empty() ? "" : ", ", c);
  return out;
}

// Markdown without its markup, for a terminal: `code` -> code, [text](link) -> text.
std::string plain(std::string_view md) {
  std::string out;
  for (std::size_t i = 0; i < md.size(); ++i) {
    if (md[i] == '`')
      continue;
    if (md[i] == '[') {
      const auto close = md.find("](", i);
      const auto end = close == std::string_view::npos ? close : md.find(')', close);
      if (end != std::string_view::npos && md.find('[', i + 1) > close) {
        out += md.substr(i + 1, close - i - 1);
        i = end;
        continue;
      }
    }
    out += md[i];
  }
  return out;
}

// `text` broken into lines of at most `width` characters, each after `indent` spaces.
std::string wrapped(std::string_view text, std::size_t indent, std::size_t width) {
  std::string out, line;
  const auto emit = [&] {
    out.append(indent, ' ').append(line).append("\n");
    line.clear();
  };
  std::size_t start = 0;
  while (start < text.size()) {
    std::size_t end = text.find(' ', start);
    if (end == std::string_view::npos)
      end = text.size();
    const std::string_view w = text.substr(start, end - start);
    if (!line.empty() && indent + line.size() + 1 + w.size() > width)
      emit();
    if (!line.empty())
      line += ' ';
    line += w;
    start = end + 1;
  }
  if (!line.empty())
    emit();
  return out;
}

// Type, unit and allowed values in a few words ("number, N/m, > 0").
std::string type_line(const SceneKey& k) {
  std::string out(type_word(k.type));
  if (!k.unit.empty())
    out += fmt::format(", {}", k.unit);
  if (const std::string a = plain(allowed_md(k)); !a.empty())
    out += fmt::format(", {}", a);
  return out;
}

// A table cell: a '|' in the text would end the cell.
std::string md_cell(std::string_view s) {
  std::string out;
  for (char c : s)
    out += c == '|' ? std::string("\\|") : std::string(1, c);
  return out;
}

} // namespace

std::string keys_help_text() {
  std::string out = "Scene keys (TOML, dotted; each can be overridden as key=value on the command "
                    "line;\n`cfddem keys` says what each one means):\n";
  for (const SectionText& s : kSections) {
    out += fmt::format(" {}:\n", plain(s.title));
    for (const SceneKey& k : scene_keys()) {
      if (k.section != s.section)
        continue;
      const std::string head = fmt::format("  {:<31} {}", k.name, type_line(k));
      const std::string def = k.fallback.kind == KeyDefault::Kind::Required
                                  ? plain(default_md(k))
                                  : fmt::format("default: {}", plain(default_md(k)));
      out += head.size() + 2 + def.size() <= 100 ? fmt::format("{}; {}\n", head, def)
                                                 : head + "\n" + wrapped(def, 34, 100);
    }
  }
  return out;
}

std::string keys_text() {
  std::string out;
  for (const SectionText& s : kSections) {
    out += fmt::format("{}\n", plain(s.title));
    if (!s.intro.empty())
      out += wrapped(plain(s.intro), 2, 100);
    for (const SceneKey& k : scene_keys()) {
      if (k.section != s.section)
        continue;
      out += fmt::format("  {}  ({}; default: {})\n", k.name, type_line(k), plain(default_md(k)));
      out += wrapped(plain(k.meaning), 6, 100);
    }
    if (!s.outro.empty())
      out += wrapped(plain(s.outro), 2, 100);
    out += "\n";
  }
  return out;
}

std::string keys_markdown() {
  std::string out(kIntro);
  for (const SectionText& s : kSections) {
    out += fmt::format("\n## {}\n\n", s.title);
    if (!s.intro.empty())
      out += fmt::format("{}\n\n", s.intro);
    out += "| key | type | unit | allowed | default | meaning |\n|---|---|---|---|---|---|\n";
    // Neighbouring keys that differ only in name share a row (domain.lo, domain.hi).
    std::vector<const SceneKey*> row;
    const auto cells = [](const SceneKey& k) {
      return fmt::format("{} | {} | {} | {} | {}", md_cell(type_word(k.type)), md_cell(k.unit),
                         md_cell(allowed_md(k)), md_cell(default_md(k)), md_cell(k.meaning));
    };
    const auto flush = [&] {
      if (row.empty())
        return;
      std::string names;
      for (const SceneKey* k : row)
        names += fmt::format("{}`{}`", names.empty() ? "" : ", ", k->name);
      out += fmt::format("| {} | {} |\n", names, cells(*row.front()));
      row.clear();
    };
    for (const SceneKey& k : scene_keys()) {
      if (k.section != s.section)
        continue;
      if (!row.empty() && cells(*row.front()) != cells(k))
        flush();
      row.push_back(&k);
    }
    flush();
    if (!s.outro.empty())
      out += fmt::format("\n{}\n", s.outro);
  }
  // The restart's keys from its own rule, not a copy of it.
  std::string outro(kOutro);
  const std::string_view mark = "@RESTART_KEYS@";
  outro.replace(outro.find(mark), mark.size(), restart_free_keys_text(true));
  out += fmt::format("\n{}", outro);
  return out;
}

} // namespace cfddem
