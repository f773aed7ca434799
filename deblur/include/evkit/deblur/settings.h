// A method's settings, each declared once: its key, its type, its range and its help; the default
// is the options struct's own value. Parsing `--set KEY=VALUE`, checking an options struct built in
// C++ (check()), the help text and the unknown-key message all come from that one declaration,
// as COLMAP's option manager does for its options.
//
//   SettingsTable<EdiOptions> table("edi");
//   table.number("c_min", &EdiOptions::search_min, {0, 10}, "lowest contrast of the search");
//   table.apply(options, {{"c_min", "0.1"}});   // throws evkit::Error naming the key and the range
#pragma once

#include <cmath>
#include <functional>
#include <limits>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "evkit/base/error.h"

namespace evkit {

// Key/value settings of a method, from the command line ("contrast=0.2").
using MethodSettings = std::map<std::string, std::string>;

// A setting's value as a finite number; throws evkit::Error "<method>: setting KEY=VALUE is not a
// number" otherwise.
double settingNumber(const std::string& method, const std::string& key, const std::string& value);

// An inclusive range; open ends where a bound is infinite.
struct SettingRange {
  double min = -std::numeric_limits<double>::infinity();
  double max = std::numeric_limits<double>::infinity();
  bool min_open = false, max_open = false;  // (min, ... and ..., max)
  bool contains(double v) const {
    return (min_open ? v > min : v >= min) && (max_open ? v < max : v <= max);
  }
  std::string describe() const;  // "in (0, 1]", ">= 1", ...
};

// A number as --help prints it: "0.02", "1e-12", "4".
std::string shortNumber(double v);

template <typename Options>
class SettingsTable {
 public:
  struct Entry {
    std::string key, type, help;
    std::function<void(Options&, const std::string&)>
        parse;                                  // sets the value; throws when out of range
    std::function<void(const Options&)> check;  // throws when the struct's value is out of range
    std::function<std::string(const Options&)> show;  // the value, as --help prints defaults
  };

  explicit SettingsTable(std::string method) : method_(std::move(method)) {}

  SettingsTable& number(const std::string& key, double Options::*member, SettingRange range,
                        const std::string& help) {
    const std::string method = method_;
    return add(
        {key, "number", help,
         [=](Options& o, const std::string& v) {
           o.*member = inRange(method, key, v, settingNumber(method, key, v), range);
         },
         [=](const Options& o) { inRange(method, key, shortNumber(o.*member), o.*member, range); },
         [=](const Options& o) { return shortNumber(o.*member); }});
  }

  template <typename Int>
  SettingsTable& integer(const std::string& key, Int Options::*member, SettingRange range,
                         const std::string& help) {
    const std::string method = method_;
    return add({key, "integer", help,
                [=](Options& o, const std::string& v) {
                  o.*member = static_cast<Int>(integerIn(method, key, v, range));
                },
                [=](const Options& o) { integerIn(method, key, std::to_string(o.*member), range); },
                [=](const Options& o) { return std::to_string(o.*member); }});
  }

  // 0 or 1 (any number: non-zero is true).
  SettingsTable& flag(const std::string& key, bool Options::*member, const std::string& help) {
    const std::string method = method_;
    return add(
        {key, "0|1", help,
         [=](Options& o, const std::string& v) { o.*member = settingNumber(method, key, v) != 0; },
         [](const Options&) {},
         [=](const Options& o) { return std::string(o.*member ? "1" : "0"); }});
  }

  // One of named values.
  template <typename Value>
  SettingsTable& choice(const std::string& key, Value Options::*member,
                        std::vector<std::pair<std::string, Value>> names, const std::string& help) {
    std::string type;
    for (const auto& [name, value] : names) type += (type.empty() ? "" : "|") + name;
    const std::string method = method_;
    return add({key, type, help,
                [=](Options& o, const std::string& v) {
                  for (const auto& [name, value] : names) {
                    if (name == v) return void(o.*member = value);
                  }
                  throw Error(method + ": " + key + " must be " + listOr(names) + ", not '" + v +
                              "'");
                },
                [](const Options&) {},
                [=](const Options& o) {
                  for (const auto& [name, value] : names) {
                    if (o.*member == value) return name;
                  }
                  return std::string("?");
                }});
  }

  // Anything else: a parser, a check and a printer of one's own.
  SettingsTable& custom(Entry entry) { return add(std::move(entry)); }

  // Applies the settings in key order; an unknown key is one error line listing the known ones.
  void apply(Options& options, const MethodSettings& settings) const {
    for (const auto& [key, value] : settings) find(key).parse(options, value);
  }
  // Throws evkit::Error for the first value out of its range (a C++ user's options struct).
  void check(const Options& options) const {
    for (const Entry& e : entries_) e.check(options);
  }
  // "KEY (TYPE, default VALUE): HELP" per line.
  std::string help(const Options& defaults) const {
    std::string text;
    for (const Entry& e : entries_)
      text +=
          "  " + e.key + " (" + e.type + ", default " + e.show(defaults) + "): " + e.help + "\n";
    return text;
  }
  std::vector<std::string> keys() const {
    std::vector<std::string> k;
    for (const Entry& e : entries_) k.push_back(e.key);
    return k;
  }
  const std::string& method() const { return method_; }

 private:
  SettingsTable& add(Entry entry) {
    entries_.push_back(std::move(entry));
    return *this;
  }
  const Entry& find(const std::string& key) const {
    for (const Entry& e : entries_) {
      if (e.key == key) return e;
    }
    std::string known;
    for (const Entry& e : entries_) known += (known.empty() ? "" : ", ") + e.key;
    throw Error(method_ + ": unknown setting '" + key + "' (known: " + known + ")");
  }
  static double inRange(const std::string& method, const std::string& key, const std::string& text,
                        double v, const SettingRange& range) {
    if (!range.contains(v))
      throw Error(method + ": setting " + key + "=" + text + " must be " + range.describe());
    return v;
  }
  static double integerIn(const std::string& method, const std::string& key,
                          const std::string& text, const SettingRange& range) {
    const double v = settingNumber(method, key, text);
    if (v != std::floor(v) || !range.contains(v) || std::abs(v) > 1e9) {
      throw Error(method + ": setting " + key + "=" + text + " must be an integer " +
                  range.describe());
    }
    return v;
  }
  template <typename Value>
  static std::string listOr(const std::vector<std::pair<std::string, Value>>& names) {
    std::string s;
    for (size_t i = 0; i < names.size(); ++i)
      s += (i == 0 ? "" : i + 1 == names.size() ? " or " : ", ") + names[i].first;
    return s;
  }

  std::string method_;
  std::vector<Entry> entries_;
};

}  // namespace evkit
